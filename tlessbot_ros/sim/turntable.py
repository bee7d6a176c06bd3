"""Turntable mode: rendered training crops of each part, after the paper's §4.

The paper fixed one D415 on a tripod in front of an electric turntable, placed each part at four
locations on the plate and captured a view every 1° over 360°, then added shear and zoom
augmentation (30 objects × 4 × 360 × 4 = 172,800 crops). Here the same protocol is rendered
from the CAD models:

- the part rests on the plate in one of its stable poses (:func:`tlessbot_ros.io.models.
  stable_poses`), drawn per view with its drop probability, so the training views show parts
  lying as they land on the table (a physical session would re-lay the part now and then; a
  fixed pose per position left e.g. rolling cylinders, which mostly lie on their side, seen
  upright only); position ``k`` puts it ``position_radius_m`` off the plate centre;
- the plate turns in ``step_deg`` steps (the camera orbits the plate, which is the same thing for
  a static scene); the camera's elevation and distance are drawn per step from ranges that
  cover the cell's top (≈ 90°, 1.1 m) and side (≈ 50–90°, 0.5–0.8 m) views, where the paper's
  tripod stayed put — a fixed elevation would leave the test viewpoints unseen;
- each view is shaded with a random PLA material and light, and ``augmentations`` extra copies
  get a random shear, zoom (resampling) and, sometimes, a partial cut of the silhouette as
  occlusion by a neighbour would cause.

Only the window around the part is ray-cast, with the intrinsics of a 640×480 D415 colour
stream, so a view costs a few milliseconds and the apparent size of the part in pixels is what
the cell's cameras see. Every sample is deterministic given ``seed``, the object id, the
position and the step, independent of which objects or steps are requested.
"""
from __future__ import annotations

import csv
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    MeshRenderer,
    d415_intrinsics,
    invert_transform,
    look_at,
    make_transform,
    project_points,
    rotation_about_axis,
    transform_points,
)
from tlessbot_ros.io.models import ObjectModel, stable_poses
from tlessbot_ros.sim.noise import (
    DEPTH_KINDS,
    DepthNoiseParams,
    add_depth_noise,
    spread_depth_kind,
    stereo_region,
)


@dataclass(frozen=True)
class TurntableParams:
    """Turntable protocol and randomisation.

    Attributes:
        positions: places of the part on the plate (paper: 4).
        step_deg: plate rotation between views (paper: 1°).
        augmentations: extra shear/zoom copies per view (paper: 3, i.e. ×4 images).
        position_radius_m: distance of the positions from the plate centre.
        elevation_deg: (min, max) camera elevation above the plate, drawn per view.
        distance_m: (min, max) camera distance to the part, drawn per view.
        width, height: colour stream whose intrinsics are used (D415 at 640×480).
        shear_max: largest shear factor of an augmented copy.
        zoom: (min, max) resampling factor of an augmented copy.
        occlusion_prob: chance that an augmented copy loses part of its silhouette.
        occlusion_max_frac: largest fraction of the silhouette cut away.
        noise_sigma: (min, max) standard deviation of Gaussian pixel noise (grey levels).
        min_pose_probability: resting poses rarer than this are not used (0 keeps all: a
            rolling part has many rare facet poses that together are its most likely way to
            lie).
        depth_noise_scale: scale of the simulator's D415 depth noise model on the rendered
            depth (0 = clean depth).
        smoothed_depth_share: share of the views (0-1, spread evenly over positions and
            steps) whose depth is the stereo-like 'smoothed' kind; the rest are per-pixel.
        smoothed_region_px: a smoothed view's silhouette grows by up to this many pixels
            (0-3) where its depth rises above the plate, as a localiser's region does.
    """

    positions: int = 4
    step_deg: float = 1.0
    augmentations: int = 3
    position_radius_m: float = 0.08
    elevation_deg: tuple[float, float] = (45.0, 90.0)
    distance_m: tuple[float, float] = (0.45, 1.2)
    width: int = 640
    height: int = 480
    shear_max: float = 0.2
    zoom: tuple[float, float] = (0.6, 1.3)
    occlusion_prob: float = 0.3
    occlusion_max_frac: float = 0.35
    noise_sigma: tuple[float, float] = (1.0, 5.0)
    min_pose_probability: float = 0.0
    depth_noise_scale: float = 1.0
    smoothed_depth_share: float = 0.0
    smoothed_region_px: int = 1

    def __post_init__(self) -> None:
        if self.positions < 1:
            raise ValueError(f'positions must be >= 1, got {self.positions}')
        if not 0.0 < self.step_deg <= 360.0:
            raise ValueError(f'step_deg must be in (0, 360], got {self.step_deg}')
        if self.augmentations < 0:
            raise ValueError(f'augmentations must be >= 0, got {self.augmentations}')
        lo, hi = self.elevation_deg
        if not 0.0 < lo <= hi <= 90.0:
            raise ValueError(f'elevation_deg must satisfy 0 < min <= max <= 90, got {lo, hi}')
        if not 0.0 < self.distance_m[0] <= self.distance_m[1]:
            raise ValueError(f'distance_m must satisfy 0 < min <= max, got {self.distance_m}')
        if not 0.0 < self.zoom[0] <= self.zoom[1]:
            raise ValueError(f'zoom must satisfy 0 < min <= max, got {self.zoom}')
        if not 0 <= self.smoothed_region_px <= 3:
            raise ValueError(f'smoothed_region_px must be in [0, 3], got '
                             f'{self.smoothed_region_px}')
        if not 0.0 <= self.smoothed_depth_share <= 1.0:
            raise ValueError('smoothed_depth_share must be in [0, 1], got '
                             f'{self.smoothed_depth_share}')

    @property
    def steps(self) -> int:
        return int(round(360.0 / self.step_deg))

    def views_per_object(self) -> int:
        """Samples per object: positions × steps × (1 + augmentations)."""
        return self.positions * self.steps * (1 + self.augmentations)


@dataclass(frozen=True)
class TurntableSample:
    """One rendered view of one part.

    Attributes:
        obj_id: the part's id.
        rgb: (h, w, 3) uint8 colour window around the part (not yet square or 60×60).
        mask: (h, w) bool visible silhouette of the part in ``rgb``.
        position: turntable position index.
        angle_deg: plate angle.
        augmentation: 0 for the plain view, 1.. for augmented copies.
        depth_m: (h, w) float32 D415-like noisy z-depth of the window in metres (the part and
            the plate, which is the table plane z = 0), 0 = invalid; warped with the image in
            augmented copies. Its kind (``DepthNoiseParams.kind``) is ``depth_kind``.
        K: (3, 3) camera matrix of the window (for augmented copies, the warp composed with
            the intrinsics, so ``K⁻¹ [u, v, 1]ᵀ`` is still the viewing ray of pixel (u, v)).
        T_world_camera: (4, 4) camera pose in the plate (table) frame.
    """

    obj_id: int
    rgb: np.ndarray
    mask: np.ndarray
    position: int
    angle_deg: float
    augmentation: int
    depth_m: np.ndarray | None = None
    K: np.ndarray | None = None
    T_world_camera: np.ndarray | None = None
    depth_kind: str = 'per_pixel'


# PLA looks of the paper's parts (light-yellow translucent, shiny pink, black, blue) and a few
# neutral ones: albedo (linear RGB), diffuse weight, specular weight, shininess, ambient.
_MATERIALS = (
    ((0.93, 0.86, 0.55), 0.55, 0.15, 20.0, 0.40),  # light-yellow translucent: soft shading
    ((0.95, 0.45, 0.62), 0.80, 0.45, 60.0, 0.18),  # shiny pink
    ((0.07, 0.07, 0.08), 0.85, 0.35, 40.0, 0.15),  # black
    ((0.12, 0.28, 0.75), 0.80, 0.25, 30.0, 0.18),  # blue
    ((0.85, 0.85, 0.82), 0.80, 0.15, 15.0, 0.20),  # white / light grey
    ((0.45, 0.47, 0.50), 0.80, 0.20, 20.0, 0.20),  # grey
)


def _shade(normals_c: np.ndarray, rays_c: np.ndarray, hit: np.ndarray, light_c: np.ndarray,
           material: tuple, background: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Lambert + Blinn-Phong + ambient shading; (h, w, 3) float32 in [0, 1].

    TODO: switch to the simulator's shared shading (sim/shading.py) once it exists.
    """
    albedo, kd, ks, shininess, ambient = material
    albedo = np.clip(np.asarray(albedo) * rng.uniform(0.85, 1.15, 3), 0.0, 1.0)
    lambert = np.clip(normals_c @ light_c, 0.0, None)
    half = light_c[None, None, :] - rays_c
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    spec = np.clip(np.sum(normals_c * half, axis=-1), 0.0, None) ** shininess
    intensity = rng.uniform(0.7, 1.2)
    colour = (albedo[None, None, :] * (ambient + kd * intensity * lambert[..., None])
              + ks * intensity * spec[..., None])
    return np.where(hit[..., None], colour, background).astype(np.float32)


def _background(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    base = rng.uniform(0.05, 0.95, 3)
    if rng.random() < 0.5:
        return np.broadcast_to(base, (*shape, 3)).astype(np.float32)
    noise = rng.normal(0.0, 1.0, (*shape, 1)).astype(np.float32)
    noise = cv2.GaussianBlur(noise, (0, 0), rng.uniform(0.7, 3.0))[..., None]
    noise /= max(float(noise.std()), 1e-6)
    return np.clip(base + 0.12 * noise, 0.0, 1.0).astype(np.float32)


def augment_view(rgb: np.ndarray, mask: np.ndarray, params: TurntableParams,
                 rng: np.random.Generator, depth_m: np.ndarray, K: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Random shear and zoom about the silhouette centre, then an optional occlusion cut.

    The depth is warped with the image (nearest neighbour) and the returned camera matrix is
    the warp composed with ``K``, so the warped pixels still back-project to the same points.
    """
    h, w = mask.shape
    zoom = rng.uniform(*params.zoom)
    shear = rng.uniform(-params.shear_max, params.shear_max, 2)
    A = zoom * np.array([[1.0, shear[0]], [shear[1], 1.0]])
    rows, cols = np.nonzero(mask)
    centre = np.array([cols.mean(), rows.mean()])
    out_w, out_h = max(int(round(w * zoom * 1.3)), 8), max(int(round(h * zoom * 1.3)), 8)
    offset = np.array([out_w / 2.0, out_h / 2.0]) - A @ centre
    M = np.hstack([A, offset[:, None]])
    image = cv2.warpAffine(rgb, M, (out_w, out_h), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT_101)
    warped = cv2.warpAffine(mask.astype(np.float32), M, (out_w, out_h),
                            flags=cv2.INTER_LINEAR) > 0.5
    depth = cv2.warpAffine(depth_m, M, (out_w, out_h), flags=cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    K_warped = np.vstack([M, [0.0, 0.0, 1.0]]) @ K
    if rng.random() < params.occlusion_prob and warped.sum() > 50:
        # A neighbour hides the part beyond a random straight edge.
        angle = rng.uniform(0.0, 2.0 * np.pi)
        r, c = np.nonzero(warped)
        proj = c * np.cos(angle) + r * np.sin(angle)
        cut = np.quantile(proj, 1.0 - rng.uniform(0.1, params.occlusion_max_frac))
        yy, xx = np.mgrid[0:out_h, 0:out_w]
        hidden = (xx * np.cos(angle) + yy * np.sin(angle)) > cut
        warped &= ~hidden
        image[hidden] = (rng.uniform(0.0, 255.0, 3)).astype(np.uint8)
    if not warped.any():
        return rgb, mask, depth_m, K
    return image, warped, depth, K_warped


class Turntable:
    """Renders the turntable views of a set of models.

    Args:
        models: object id -> :class:`~tlessbot_ros.io.models.ObjectModel` (metres).
        params: protocol and randomisation.
        seed: base seed; views depend only on (seed, object id, position, step, copy).
    """

    def __init__(self, models: dict[int, ObjectModel], *,
                 params: TurntableParams = TurntableParams(), seed: int = 0) -> None:
        if not models:
            raise ValueError('no models given')
        self.models = models
        self.params = params
        self.seed = int(seed)
        self._full = d415_intrinsics(params.width, params.height)
        per_pixel = replace(DepthNoiseParams(), scale=params.depth_noise_scale)
        self._noise = {kind: replace(per_pixel, kind=kind) for kind in DEPTH_KINDS}

    def __len__(self) -> int:
        return len(self.models) * self.params.views_per_object()

    def _placement(self, pose: np.ndarray, position: int) -> np.ndarray:
        phi = 2.0 * np.pi * position / self.params.positions
        offset = self.params.position_radius_m * np.array([np.cos(phi), np.sin(phi), 0.0])
        return make_transform(np.eye(3), offset) @ pose

    def views(self, obj_id: int, position: int, *,
              steps: Sequence[int] | None = None) -> Iterator[TurntableSample]:
        """All samples of one object at one position (each step: plain view then its copies)."""
        model = self.models[obj_id]
        p = self.params
        poses = stable_poses(model, min_probability=p.min_pose_probability)
        probs = np.array([pose.probability for pose in poses])
        probs /= probs.sum()
        placed: dict[int, tuple] = {}  # resting pose index -> (renderer, box corners, centre)
        for step in (range(p.steps) if steps is None else steps):
            rng = np.random.default_rng([self.seed, obj_id, position, step])
            pose_index = int(rng.choice(len(poses), p=probs))
            if pose_index not in placed:
                T_world_object = self._placement(poses[pose_index].T_table_object, position)
                renderer = MeshRenderer()
                renderer.add_mesh(model.vertices, model.faces, T_world_object)
                corners = transform_points(T_world_object, _box_corners(model.vertices))
                placed[pose_index] = (renderer, corners, corners.mean(axis=0))
            renderer, corners, centre = placed[pose_index]
            angle = step * p.step_deg
            T_world_camera = self._camera(angle, centre, rng)
            kind = spread_depth_kind(position * p.steps + step, p.smoothed_depth_share)
            rgb, mask, depth, K = self._render(renderer, corners, T_world_camera, rng,
                                               self._noise[kind])
            if not mask.any():
                continue
            if kind == 'smoothed':
                mask = stereo_region(mask, depth, K, T_world_camera,
                                     grow_px=p.smoothed_region_px)
            yield TurntableSample(obj_id, rgb, mask, position, angle, 0, depth, K,
                                  T_world_camera, kind)
            for copy in range(1, p.augmentations + 1):
                aug_rgb, aug_mask, aug_depth, aug_K = augment_view(rgb, mask, p, rng, depth,
                                                                   K)
                yield TurntableSample(obj_id, aug_rgb, aug_mask, position, angle, copy,
                                      aug_depth, aug_K, T_world_camera, kind)

    def samples(self, obj_ids: Sequence[int] | None = None) -> Iterator[TurntableSample]:
        """Every sample of the chosen objects (default all), object by object."""
        for obj_id in (sorted(self.models) if obj_ids is None else obj_ids):
            for position in range(self.params.positions):
                yield from self.views(obj_id, position)

    def _camera(self, angle_deg: float, centre: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        p = self.params
        elevation = np.radians(rng.uniform(*p.elevation_deg))
        distance = rng.uniform(*p.distance_m)
        # The tripod stands on the -y side; turning the plate by +angle = orbiting by -angle.
        R_plate = rotation_about_axis(np.array([0.0, 0.0, 1.0]), -np.radians(angle_deg))
        front = R_plate @ np.array([0.0, -1.0, 0.0])
        eye = centre + distance * (np.cos(elevation) * front
                                   + np.sin(elevation) * np.array([0.0, 0.0, 1.0]))
        # Aim near the part, as the plate centre would be: a small random off-axis angle.
        target = centre + rng.normal(0.0, 0.02, 3) * np.array([1.0, 1.0, 0.0])
        up = R_plate @ np.array([0.0, 1.0, 1.0])
        return look_at(eye, target, up)

    def _render(self, renderer: MeshRenderer, corners_w: np.ndarray, T_world_camera: np.ndarray,
                rng: np.random.Generator, noise: DepthNoiseParams
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Colour, silhouette, noisy depth (part on the plate) and K of the part's window."""
        full = self._full
        uv = project_points(transform_points(invert_transform(T_world_camera), corners_w),
                            full.K)
        lo = np.floor(uv.min(axis=0)).astype(int) - 3
        hi = np.ceil(uv.max(axis=0)).astype(int) + 4
        w, h = int(hi[0] - lo[0]), int(hi[1] - lo[1])
        K = full.K.copy()
        K[0, 2] -= lo[0]
        K[1, 2] -= lo[1]
        window = CameraIntrinsics(width=w, height=h, K=K)
        result = renderer.render(window, T_world_camera)
        hit = result.depth_m > 0
        azimuth = rng.uniform(0.0, 2.0 * np.pi)
        elevation = rng.uniform(np.radians(25.0), np.radians(85.0))
        # Light direction towards the light, in the camera frame; it comes from above the part.
        light_w = np.array([np.cos(elevation) * np.cos(azimuth),
                            np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
        light_c = T_world_camera[:3, :3].T @ light_w
        material = _MATERIALS[rng.integers(len(_MATERIALS))]
        colour = _shade(result.normals_c, result.ray_dirs_c, hit, light_c, material,
                        _background((h, w), rng), rng)
        colour += rng.normal(0.0, rng.uniform(*self.params.noise_sigma) / 255.0, colour.shape)
        rgb = (np.clip(colour, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        depth = np.where(hit, result.depth_m, _plane_depth(K, (h, w), T_world_camera))
        depth_mm = add_depth_noise(depth.astype(np.float32), float(K[0, 0]), rng, noise)
        return rgb, hit, depth_mm.astype(np.float32) / 1000.0, K


def _plane_depth(K: np.ndarray, shape: tuple[int, int], T_world_camera: np.ndarray
                 ) -> np.ndarray:
    """(h, w) float32 z-depth of the plate (table plane z = 0), 0 where it is not seen."""
    h, w = shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    dz = R[2, 0] * x + R[2, 1] * y + R[2, 2]  # world z of the ray with unit optical z
    with np.errstate(divide='ignore', invalid='ignore'):
        depth = np.where(dz < -1e-9, -t[2] / dz, 0.0)
    return depth.astype(np.float32)


def _box_corners(vertices: np.ndarray) -> np.ndarray:
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                     for z in (lo[2], hi[2])])


def square_crop(sample: TurntableSample, crop_px: int = 60,
                margin_frac: float = 0.06) -> np.ndarray:
    """(crop_px, crop_px, 4) uint8 RGBA crop of a sample, square around its silhouette box, with
    the silhouette as alpha: the on-disk form that ``tlessbot train --from-images`` reads."""
    rows, cols = np.nonzero(sample.mask)
    x0, y0 = cols.min(), rows.min()
    w, h = cols.max() - x0 + 1, rows.max() - y0 + 1
    side = max(int(round(max(w, h) * (1.0 + 2.0 * margin_frac))), 2)
    left, top = int(round(x0 + w / 2.0 - side / 2.0)), int(round(y0 + h / 2.0 - side / 2.0))
    rgba = np.dstack([sample.rgb, sample.mask.astype(np.uint8) * 255])
    pad = side  # enough for any window that overlaps the image
    rgba = cv2.copyMakeBorder(rgba, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
    square = rgba[top + pad:top + pad + side, left + pad:left + pad + side]
    interp = cv2.INTER_AREA if side > crop_px else cv2.INTER_LINEAR
    return cv2.resize(square, (crop_px, crop_px), interpolation=interp)


def write_samples(samples: Iterator[TurntableSample], out_dir: str | Path, *,
                  crop_px: int = 60) -> int:
    """Write samples as ``<out_dir>/<obj_id>/<nnnnnn>.png`` RGBA crops (alpha = silhouette) and
    ``<out_dir>/labels.csv`` (file, obj_id, position, angle_deg, augmentation).

    Returns:
        The number of images written.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    count = 0
    with open(out_dir / 'labels.csv', 'w', newline='', encoding='utf-8') as handle:
        writer = csv.writer(handle)
        writer.writerow(['file', 'obj_id', 'position', 'angle_deg', 'augmentation'])
        for sample in samples:
            folder = out_dir / str(sample.obj_id)
            folder.mkdir(exist_ok=True)
            name = f'{sample.obj_id}/{count:06d}.png'
            rgba = square_crop(sample, crop_px)
            cv2.imwrite(str(out_dir / name), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
            writer.writerow([name, sample.obj_id, sample.position, f'{sample.angle_deg:g}',
                             sample.augmentation])
            count += 1
    return count
