"""Symmetry detection from a closed mesh.

:func:`detect_symmetries` tests candidate rotations about the principal axes of the surface:
the surface is sampled uniformly (:func:`~tlessbot_ros.core.common.sampling.sample_surface`),
rotated, and compared with itself by nearest-neighbour distance against a tolerance relative
to the model diameter. A flat part's outline along its thin axis, holes included, must also
stay (:mod:`.outline`): the area-weighted test lets its two large faces outvote a hole. The
result is a :class:`~tlessbot_ros.core.common.symmetry.Symmetries`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common.geometry import (
    make_transform,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.common.outline import OutlineTest, outline_test
from tlessbot_ros.core.common.render import o3d_tensor
from tlessbot_ros.core.common.sampling import sample_surface
from tlessbot_ros.core.common.symmetry import Symmetries

# The sampling scheme of the detector (see tlessbot_ros.core.common.sampling). 'reflect' finds
# the same groups on the 23 T-LESS CAD models, but the refined transforms move by up to 0.1°
# and 0.85 mm, so the detected symmetries (and models-info output) would no longer be the
# same numbers.
_SCHEME = 'sqrt'


@dataclass(frozen=True)
class SymmetryParams:
    """Tuning of :func:`detect_symmetries`.

    Attributes:
        samples: surface points used to query the nearest-neighbour test.
        reference_samples: surface points in the KD-tree the rotated samples are compared with.
        tolerance: a rotation is a symmetry when the ``quantile`` of the nearest-neighbour
            distances is below ``tolerance * diameter``.
        continuous_tolerance: the same for the rotations that test a continuous axis (a
            revolved CAD part has small features that break it slightly at most angles).
        quantile: which quantile of the distances is tested (robust to small features).
        continuous_angles_deg: rotation angles that must all pass for a continuous axis.
        plane_scan_step_deg: step when searching 2-fold axes in a plane of degenerate
            principal axes (rotationally symmetric in that plane).
        max_axis_deviation_deg: candidate axes closer than this are the same axis, and a
            refined symmetry may deviate this much from the candidate rotation.
        icp_iterations: trimmed ICP iterations refining each candidate rotation.
        seed: seed of the surface sampling.
        flat_ratio, outline_px, outline_samples, outline_share: a part whose thinnest
            extent is at most ``flat_ratio`` of its middle one must also keep its outline:
            :func:`~tlessbot_ros.core.common.outline.outline_test` (pixel: share of diameter).
    """

    samples: int = 1500
    reference_samples: int = 10000
    tolerance: float = 0.01
    continuous_tolerance: float = 0.02
    quantile: float = 0.8
    continuous_angles_deg: tuple[float, ...] = (7.0, 23.0, 45.0, 90.0, 131.0, 180.0, 217.0)
    plane_scan_step_deg: float = 2.0
    max_axis_deviation_deg: float = 10.0
    icp_iterations: int = 8
    seed: int = 0
    flat_ratio: float = 0.3
    outline_px: float = 0.01
    outline_samples: int = 60000
    outline_share: float = 0.003


def _kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation mapping (N, 3) source onto (N, 3) target."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    U, _, Vt = np.linalg.svd((source - mu_s).T @ (target - mu_t))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


class _SurfaceTest:
    """Nearest-neighbour test of rigid transforms against the sampled surface.

    A candidate rotation about an estimated axis is first refined by a few trimmed ICP
    iterations (the principal axes of a real CAD model are a little off the true symmetry axis
    because of small asymmetric features), then judged by the quantile of the distances.
    """

    def __init__(self, query: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 threshold: float, quantile: float, icp_iterations: int,
                 outline: OutlineTest | None = None) -> None:
        self.query = query
        self.outline = outline
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d_tensor(np.asarray(vertices, np.float32)),
                                 o3d_tensor(np.asarray(faces, np.uint32)))
        self.threshold = threshold
        self.quantile = quantile
        self.icp_iterations = icp_iterations

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points of (N, 3) points and the distances to them."""
        result = self.scene.compute_closest_points(o3d_tensor(points.astype(np.float32)))
        closest = result['points'].numpy().astype(np.float64)
        return closest, np.linalg.norm(closest - points, axis=1)

    def error(self, R: np.ndarray, centre: np.ndarray) -> float:
        """Distance quantile of the samples rotated by ``R`` about ``centre``."""
        return float(np.quantile(self.closest((self.query - centre) @ R.T + centre)[1],
                                 self.quantile))

    def holds(self, R: np.ndarray, centre: np.ndarray) -> bool:
        """Whether the rotation ``R`` about ``centre`` maps the surface (and the outline of a
        flat part) onto itself, unrefined."""
        if self.error(R, centre) > self.threshold:
            return False
        return self.outline is None or not self.outline.moves(make_transform(R, centre -
                                                                             R @ centre))

    def refine(self, R: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, float]:
        """Refined (4, 4) transform near the rotation ``R`` about ``centre``, and its error."""
        t = centre - R @ centre
        for _ in range(self.icp_iterations):
            closest, distances = self.closest(self.query @ R.T + t)
            keep = distances <= np.quantile(distances, self.quantile)
            R, t = _kabsch(self.query[keep], closest[keep])
        distances = self.closest(self.query @ R.T + t)[1]
        return make_transform(R, t), float(np.quantile(distances, self.quantile))

    def check(self, axis: np.ndarray, angle_rad: float, centre: np.ndarray,
              max_deviation_rad: float, *, threshold: float | None = None) -> np.ndarray | None:
        """The refined symmetry near the rotation (axis, angle) about centre, or None.

        None when the refined transform does not map the surface onto itself, or when ICP slid
        to a different rotation (axis or angle off by more than ``max_deviation_rad``).
        """
        T, error = self.refine(rotation_about_axis(axis, angle_rad), centre)
        if error > (self.threshold if threshold is None else threshold):
            return None
        if self.outline is not None and self.outline.moves(T):
            return None
        wrapped = np.arccos(np.cos(angle_rad))  # the rotation angle in [0, pi]
        if abs(_angle(T) - wrapped) > max_deviation_rad:
            return None
        if angle_rad > 1e-3 and np.arccos(min(1.0, abs(_mean_axis([T[:3, :3]], axis) @ axis))) \
                > max_deviation_rad:
            return None
        return T


def _perpendicular(axis: np.ndarray) -> np.ndarray:
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    v = np.cross(axis, helper)
    return cast(np.ndarray, v / np.linalg.norm(v))


_GROUP_LIMIT = 48   # rotations in a closed group at most: more means inconsistent generators


def _close_group(rotations: list[np.ndarray], *, tolerance_deg: float = 3.0,
                 limit: int = _GROUP_LIMIT) -> list[np.ndarray]:
    """The finite rotation group generated by ``rotations`` (identity first).

    Rotations closer than ``tolerance_deg`` are merged, so slightly inconsistent generators
    (measured on a real mesh) cannot generate an endless group.
    """
    group = [np.eye(3)]

    def known(R: np.ndarray) -> bool:
        return any(rotation_angle_deg(R, G) < tolerance_deg for G in group)

    pending = list(rotations)
    while pending and len(group) < limit:
        R = pending.pop(0)
        if known(R):
            continue
        group.append(R)
        pending.extend(R @ G for G in list(group))
        pending.extend(G @ R for G in list(group))
    return group


def detect_symmetries(vertices: np.ndarray, faces: np.ndarray, *,
                      params: SymmetryParams = SymmetryParams(),
                      diameter: float | None = None) -> Symmetries:
    """Detect the discrete and continuous rotational symmetries of a mesh.

    Method: the surface is sampled uniformly; its area-weighted centroid and principal axes
    (eigenvectors of the covariance) are computed, since every symmetry fixes the centroid and
    maps principal axes to principal axes. For each principal axis:

    * continuous: the surface maps onto itself for all of ``params.continuous_angles_deg``;
    * n-fold (n in 2, 3, 4, 6): the rotation by 360°/n maps the surface onto itself.

    For 2-fold flips perpendicular to a continuous or n-fold (n >= 3) axis, where the two other
    principal axes are degenerate, candidate axes in that plane are scanned. The discrete set is
    closed into a group. "Maps onto itself" means the ``quantile`` of nearest-neighbour distances
    between the rotated samples and a denser reference sample is below
    ``tolerance * diameter``.

    Args:
        vertices: (V, 3) vertex positions in metres (model frame).
        faces: (F, 3) int vertex indices.
        params: detection settings.
        diameter: the model diameter in metres (default: estimated from the samples).

    Returns:
        :class:`Symmetries` with transforms about the surface centroid (metres).
    """
    reference, _ = sample_surface(vertices, faces, params.reference_samples, seed=params.seed,
                                  scheme=_SCHEME)
    query, _ = sample_surface(vertices, faces, params.samples, seed=params.seed + 1,
                              scheme=_SCHEME)
    if diameter is None:
        far = reference[np.argsort(np.linalg.norm(reference - reference.mean(0), axis=1))
                        [-min(len(reference), 500):]]
        diameter = float(np.linalg.norm(far[:, None] - far[None], axis=-1).max())
    centre = reference.mean(axis=0)
    _, principal = np.linalg.eigh(np.cov((reference - centre).T))
    test = _SurfaceTest(query, vertices, faces, params.tolerance * diameter, params.quantile,
                        params.icp_iterations,
                        outline_test(vertices, faces, reference, flat_ratio=params.flat_ratio,
                                     pixel_m=params.outline_px * diameter,
                                     samples=params.outline_samples, scheme=_SCHEME,
                                     share=params.outline_share, seed=params.seed + 2))
    deviation = np.radians(params.max_axis_deviation_deg)
    candidates: list[np.ndarray] = []
    # the model frame's axes first (CAD frames are usually aligned with the symmetry axes),
    # then the principal axes
    for axis in [*np.eye(3), *principal.T]:
        if all(abs(axis @ c) < np.cos(np.radians(3.0)) for c in candidates):
            candidates.append(axis / np.linalg.norm(axis))

    continuous_axis, centre = _continuous_axis(test, candidates, centre, deviation,
                                               params.continuous_angles_deg,
                                               params.continuous_tolerance * diameter)
    generators: list[np.ndarray] = []
    special = continuous_axis
    fold_of_special = 0
    if continuous_axis is None:
        generators, special, fold_of_special = _n_fold_generators(test, candidates, centre,
                                                                  deviation)
    if special is not None and not _half_turn_across(generators, special, deviation):
        flip = _perpendicular_flip(test, special, centre, deviation,
                                   continuous=continuous_axis is not None,
                                   fold=fold_of_special, step_deg=params.plane_scan_step_deg)
        if flip is not None:
            generators.append(flip)
    group = _close_group(generators, limit=_GROUP_LIMIT)
    if len(group) >= _GROUP_LIMIT:
        # inconsistent generators (an axis a degree off): keep the rotations that hold
        group = [R for R in group if test.holds(R, centre)]
    discrete = tuple(make_transform(R, centre - R @ centre) for R in group)
    if continuous_axis is not None:
        continuous_axis = continuous_axis * (1 if continuous_axis[np.argmax(np.abs(
            continuous_axis))] > 0 else -1)
    continuous = ((continuous_axis, centre),) if continuous_axis is not None else ()
    return Symmetries(discrete=discrete, continuous=continuous)


def _continuous_axis(test: _SurfaceTest, candidates: list[np.ndarray], centre: np.ndarray,
                     deviation: float, angles_deg: tuple[float, ...], threshold: float
                     ) -> tuple[np.ndarray | None, np.ndarray]:
    """The first candidate axis the surface turns about by every one of ``angles_deg`` (its
    refined direction, or None), and the centre: on that axis when one is found."""
    for axis in candidates:
        found = []
        for angle in angles_deg:
            T = test.check(axis, np.radians(angle), centre, deviation, threshold=threshold)
            if T is None:
                break
            found.append(T)
        else:
            continuous_axis = _mean_axis([T[:3, :3] for T in found], axis)
            if any(_angle(T) > 0.3 for T in found):
                # the rotations fix the axis line, not a point on it: keep the surface
                # centroid's place along the axis (a tube's flip of its alike ends turns about
                # a point there, wherever the CAD origin lies)
                point = np.mean([_axis_point(T) for T in found if _angle(T) > 0.3], axis=0)
                centre = point + ((centre - point) @ continuous_axis) * continuous_axis
            return continuous_axis, centre
    return None, centre


def _n_fold_generators(test: _SurfaceTest, candidates: list[np.ndarray], centre: np.ndarray,
                       deviation: float) -> tuple[list[np.ndarray], np.ndarray | None, int]:
    """Rotations by 360°/n (n in 2, 3, 4, 6) about the candidate axes that map the surface onto
    itself, and the axis of the highest fold above 2 (None) with that fold (0)."""
    generators: list[np.ndarray] = []
    special, fold_of_special = None, 0
    for axis in candidates:
        fold = 0
        found = None
        for n in (2, 3):
            T = test.check(axis, 2 * np.pi / n, centre, deviation)
            if T is not None:
                fold, found = n, T
        if fold and test.check(axis, np.pi / fold, centre, deviation) is not None:
            fold *= 2  # 4-fold or 6-fold
        if fold and found is not None:
            refined = _mean_axis([found[:3, :3]], axis)
            generators.append(rotation_about_axis(refined, 2 * np.pi / fold))
            if fold > fold_of_special and fold > 2:
                special, fold_of_special = refined, fold
    return generators, special, fold_of_special


def _perpendicular_flip(test: _SurfaceTest, special: np.ndarray, centre: np.ndarray,
                        deviation: float, *, continuous: bool, fold: int,
                        step_deg: float) -> np.ndarray | None:
    """A 2-fold rotation about an axis perpendicular to a continuous or n-fold (n >= 3) axis
    that maps the surface onto itself, or None."""
    # With a continuous axis any one of them will do; with an n-fold axis they repeat every
    # 180°/n.
    u = _perpendicular(special)
    v = np.cross(special, u)
    span = 1.0 if continuous else 180.0 / max(fold, 2)
    best_flip = None
    for a in np.arange(0.0, span, step_deg):
        flip_axis = np.cos(np.radians(a)) * u + np.sin(np.radians(a)) * v
        error = test.error(rotation_about_axis(flip_axis, np.pi), centre)
        if best_flip is None or error < best_flip[0]:
            best_flip = (error, flip_axis)
    if best_flip is None:
        return None
    T = test.check(best_flip[1], np.pi, centre, deviation)
    if T is None:
        return None
    flip = _mean_axis([T[:3, :3]], best_flip[1])
    flip = flip - (flip @ special) * special  # exactly perpendicular
    return rotation_about_axis(flip / np.linalg.norm(flip), np.pi)


def _half_turn_across(rotations: list[np.ndarray], axis: np.ndarray, deviation: float) -> bool:
    """Whether ``rotations`` hold a half turn about an axis perpendicular to ``axis``: the flip
    the plane scan looks for, found among the candidates already (the scan's, a degree off it,
    would generate rotations without end)."""
    return any(_angle(make_transform(R, np.zeros(3))) > np.pi - deviation and
               abs(_mean_axis([R], axis) @ axis) < np.sin(deviation) for R in rotations)


def _angle(T: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))


def _mean_axis(rotations: list[np.ndarray], reference: np.ndarray) -> np.ndarray:
    """Mean rotation axis of rotations (sign aligned with ``reference``)."""
    axes = []
    for R in rotations:
        w, V = np.linalg.eig(R)
        axis = np.real(V[:, np.argmin(np.abs(w - 1))])
        axes.append(axis if axis @ reference >= 0 else -axis)
    mean = np.mean(axes, axis=0)
    return cast(np.ndarray, mean / np.linalg.norm(mean))


def _axis_point(T: np.ndarray) -> np.ndarray:
    """The point of the rotation axis of ``T`` closest to the origin (least squares).

    ``I - R`` is singular along the axis; a refined ``T`` is not exactly a rotation, so its
    third singular value is tiny but not zero, and solving with it would throw the point far
    along the axis. Singular values under 5 % of the largest are cut (callers pass rotations
    of more than ~17 degrees, whose other two singular values exceed 0.3).
    """
    R, t = T[:3, :3], T[:3, 3]
    return cast(np.ndarray, np.linalg.lstsq(np.eye(3) - R, t, rcond=0.05)[0])
