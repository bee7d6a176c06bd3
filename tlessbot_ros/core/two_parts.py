"""Two parts found as one are divided after the fit: the mirror of
:mod:`tlessbot_ros.core.one_part`.

Flat parts that touch on the table (a plate against a disc, a strip across a bracket's foot)
stand at the same height, often in the same colour, and the localiser finds them as one
region in both views; the region is classified as one part and fitted as one. After the fit
it shows: the fitted part explains its own depth points (inside its outline, within
``verify_inlier_m`` of its surface: the unknown rule's test,
:func:`~tlessbot_ros.core.part_fit.outline_shares`), and the other part's points are left
over as one connected piece. A rigid part cannot leave a piece of itself unexplained by a
correct fit, so a connected piece of at least ``min_roi_points`` unexplained points is
another part: it becomes its own region (in every view whose depth shows it), is classified
(the classifier where the pipeline has one, else its fit among every known part) and fitted.

The rest of the region is classified and fitted again the same way, the region's pixels go
to the one fit that explains them (those without depth to the nearer side,
:func:`reassigned`), and both sides are fitted once more on their pixels (then, for their
regions and boxes, the pixels neither fit explains go to the nearer side too). The piece is
kept only when it is a part by the rules of any region (:func:`fits_alone`: the unknown rule
on its own points, and its points cover :data:`MIN_COVERAGE` of its fitted model), the rest
still is one, neither fit explains the other's points (:func:`apart`: else one part was
fitted twice), and the piece's part is seen where it is fitted (:func:`seen_share`: its own
region covers :data:`MIN_COVERAGE` of its silhouette; a band of a plate's rim that a fit a
few millimetres off leaves unexplained is fitted as a strip lying over the plate, whose
silhouette then lies on the plate's pixels: depth 1 mm apart, which the depth cannot tell,
but two parts lying on the table cannot both be seen at one pixel). Otherwise the region is
left as it was. A kept piece may be divided again, and so may the rest, by a piece that does
not touch the one divided off (three parts in a row: a fit on the middle one leaves both ends
out, one is divided off at a time; a piece against the one divided off is more likely that
one's rim, left out by its fit on part of its pixels).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.common import depth_to_points, mask_box, transform_points
from tlessbot_ros.core.edge_bands import is_edge_band, without_label
from tlessbot_ros.core.flat_parts import check_fitted_part
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.part_fit import outline_shares, pose_stage, unknown_last
from tlessbot_ros.core.pose import inside_outline, roi_cloud
from tlessbot_ros.core.pose.silhouette import silhouette, window
from tlessbot_ros.core.recognise import UNKNOWN_ID
from tlessbot_ros.core.resting_check import check_resting_and_turns
from tlessbot_ros.core.same_part import shared_shares

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose import ObjectTemplates, Refiner

# a second way to divide a region, given the frame's fitted parts (refit_halves.py)
SecondTry = Callable[['PerceptionPipeline', PartJob, dict[str, 'ViewInput'],
                      dict[str, np.ndarray], Sequence[PartJob]], 'PartJob | None']

# A piece is a part only when its points cover at least this share of its fitted model's
# surface that faces the camera: the share of a part that must be visible for it to count
# as seen (the BOP targets' visib_fract >= 0.3).
MIN_COVERAGE = 0.3


def explained(points_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
              refiner: Refiner, inlier_m: float) -> np.ndarray:
    """(N,) bool: which of ``points_c`` (N, 3, camera frame, m) ``obj`` at ``T_camera_object``
    explains: inside its outline and within ``inlier_m`` of its surface (the unknown rule's
    two tests)."""
    model = transform_points(T_camera_object, obj.model_points.astype(np.float64))
    inside = inside_outline(points_c, model, obj.sample_spacing_m())
    near = refiner.surface_distances(points_c, obj, T_camera_object, reach_m=inlier_m)
    return np.asarray(inside & (near <= inlier_m))


def unexplained_piece(mask: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
                      obj: ObjectTemplates, T_camera_object: np.ndarray, refiner: Refiner, *,
                      inlier_m: float, min_points: int) -> np.ndarray | None:
    """(H, W) bool: the largest connected piece of ``mask``'s depth pixels that ``obj`` at
    ``T_camera_object`` (this camera's optical frame) does not explain (outside its outline or
    farther than ``inlier_m`` from its surface), with the mask's other pixels that lie nearer
    to it than to the explained ones; None when that piece has fewer than ``min_points``
    points."""
    box = mask_box(mask)
    if box[2] == 0:
        return None
    points, pixels = depth_to_points(depth_m, K, mask=mask, box=box)
    if len(points) < min_points:
        return None
    bad = ~explained(points.astype(np.float64), obj, T_camera_object, refiner, inlier_m)
    if np.count_nonzero(bad) < min_points:
        return None
    x0, y0, w, h = box
    marks = np.zeros((h, w), np.uint8)
    marks[pixels[bad, 0] - y0, pixels[bad, 1] - x0] = 1
    count, components = cv2.connectedComponents(marks, connectivity=8)
    sizes = np.bincount(components[marks > 0], minlength=count)
    sizes[0] = 0
    biggest = int(np.argmax(sizes))
    if sizes[biggest] < min_points:
        return None
    piece = components == biggest
    kept = np.zeros((h, w), np.uint8)
    kept[pixels[~bad, 0] - y0, pixels[~bad, 1] - x0] = 1
    # the mask's other pixels (no depth, or unexplained specks) go to the nearer side
    to_piece = cv2.distanceTransform((~piece).astype(np.uint8), cv2.DIST_L2, 3)
    to_rest = cv2.distanceTransform(1 - kept, cv2.DIST_L2, 3) if kept.any() else \
        np.full((h, w), np.inf, np.float32)
    window = mask[y0:y0 + h, x0:x0 + w]
    out = np.zeros(mask.shape, bool)
    out[y0:y0 + h, x0:x0 + w] = window & (piece | ((kept == 0) & (to_piece < to_rest)))
    return out


def piece_in_views(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                   labels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per view that sees ``job``'s part with depth and a table frame: the piece of its
    region that the fit leaves unexplained (:func:`unexplained_piece`), in the fitted view
    first; {} when the fitted view has none."""
    detection = job.detection
    estimator = pose_stage(pipeline.pose_estimator)
    assert detection.pose is not None
    obj = estimator.database[detection.obj_id]
    p = pipeline.fit_params
    fit_view = views[detection.view]
    pieces: dict[str, np.ndarray] = {}
    for name in [detection.view] + [v for v in labels if v != detection.view]:
        view = views.get(name)
        if view is None or view.depth_m is None:
            continue
        if name == detection.view:
            T = detection.pose.T_camera_object
        elif view.T_world_camera is None or fit_view.T_world_camera is None:
            continue
        else:
            T = np.linalg.inv(view.T_world_camera) @ fit_view.T_world_camera @ \
                detection.pose.T_camera_object
        region = labels[name] == detection.instance_id
        piece = unexplained_piece(region, view.depth_m, view.intrinsics.K, obj, T,
                                  estimator.refiner, inlier_m=p.verify_inlier_m,
                                  min_points=p.min_roi_points)
        if piece is None and name == detection.view:
            return {}
        if piece is not None:
            pieces[name] = piece
    return pieces


def split_then(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
               labels: dict[str, np.ndarray], jobs: Sequence[PartJob],
               judge: Callable[[Detection], None], publish: Callable[[Detection], None], *,
               box_mode: bool = False, found: list[Detection] | None = None,
               second_try: SecondTry | None = None
               ) -> tuple[Callable[[Detection], None], list[Detection]]:
    """``judge`` (the unknown rule, then ``publish``) behind the division of each kept part's
    region (see the module), and the list (``found``, or a new one) that each piece kept as
    a part of its own is appended to, once judged and published; ``labels`` then give it its
    own instance id in every view that shows it (arrays replaced, not written into). Off
    (``judge`` itself) with ``FitParams.split_unexplained`` off or in ``box_mode``.
    ``second_try(pipeline, job, views, labels, others)``: asked for a piece where the first
    division finds none (:func:`~tlessbot_ros.core.refit_halves.split_badly_explained`)."""
    found = [] if found is None else found
    if box_mode or not pipeline.fit_params.split_unexplained:
        return judge, found
    by_detection = {id(job.detection): job for job in jobs}

    def divided(detection: Detection) -> None:
        job = by_detection[id(detection)]
        pieces: list[PartJob] = []
        # the rest may hold a part more: a fit on the middle one of three parts in a row
        # leaves both ends out, and one piece is divided off at a time
        while detection.pose is not None and detection.obj_id != UNKNOWN_ID and \
                job.T_world_camera is not None:
            others = list(by_detection.values())
            piece = split_off(pipeline, job, views, labels, others,
                              apart_from=[p.detection.instance_id for p in pieces])
            if piece is None and not pieces and second_try is not None:
                piece = second_try(pipeline, job, views, labels, others)
            if piece is None:
                break
            by_detection[id(piece.detection)] = piece
            pieces.append(piece)
        judge(detection)
        for piece in pieces:   # a piece may hold a part more
            found.append(piece.detection)
            split_then(pipeline, views, labels, list(by_detection.values()), unknown_last(
                pipeline.fit_params, [piece], publish, pipeline.pose_estimator), publish,
                found=found, second_try=second_try)[0](piece.detection)
    return divided, found


def split_off(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
              labels: dict[str, np.ndarray], others: Sequence[PartJob] = (), *,
              apart_from: Sequence[int] = (), thick_too: bool | None = None
              ) -> PartJob | None:
    """The piece of ``job``'s region that its fit leaves unexplained, fitted, when it is a
    part (see the module) that none of ``others`` (the frame's fitted parts) sits on already
    and that does not touch the regions ``apart_from`` (pieces just divided off this region,
    in the fitted view: their fits, made on part of their pixels, can leave a rim of their
    own in the rest): ``labels`` are then divided and ``job`` (its points, box, class and
    pose) refitted on what is left; else None and nothing changed. A piece that is a band
    along the rest's edge (``FitParams.edge_band_px``) is erased instead, the rest divided
    and refitted all the same, and None returned. ``thick_too``: divide where neither side
    is flat (default ``FitParams.split_thick_parts``)."""
    if thick_too is None:
        thick_too = pipeline.fit_params.split_thick_parts
    if not pipeline.flat_ids and not thick_too:   # the depth's seams divide thick parts
        return None
    pieces = piece_in_views(pipeline, job, views, labels)
    detection = job.detection
    if not pieces or touches(pieces[detection.view], labels[detection.view], apart_from):
        return None
    new_id = 1 + max(int(image.max(initial=0)) for image in labels.values())
    if new_id > np.iinfo(labels[detection.view].dtype).max:
        return None
    divided = dict(labels)
    divided.update({name: np.where(piece, new_id, labels[name]).astype(labels[name].dtype)
                    for name, piece in pieces.items()})
    piece = divided_job(pipeline, job, views, divided, new_id)
    if piece is None or not fits_alone(pipeline, piece):
        return None
    if any(same_place(pipeline, piece, other) for other in others if other is not job):
        return None   # a part found in a region of its own too
    rest = divided_job(pipeline, job, views, divided, detection.instance_id)
    if rest is None or not fits_alone(pipeline, rest) or not apart(pipeline, piece, rest):
        return None
    if not thick_too and not {piece.detection.obj_id, rest.detection.obj_id} & \
            pipeline.flat_ids:
        return None
    view = views[detection.view]
    divided[detection.view] = reassigned(pipeline, view, divided[detection.view], rest, piece)
    for side in (rest, piece):   # once more, each on the pixels that its first fit explains
        first = dict(vars(side.detection))
        pipeline.fit_part(side)
        if side.detection.pose is None:
            vars(side.detection).update(first)
    divided[detection.view] = reassigned(pipeline, view, divided[detection.view], rest, piece)
    for fitted in (piece, rest):
        check_fitted_part(pipeline, fitted, views, divided)
        check_resting_and_turns(pipeline, fitted, views, divided)
    divided[detection.view] = reassigned(pipeline, view, divided[detection.view], rest, piece,
                                         final=True)
    for fitted in (piece, rest):
        mask = divided[detection.view] == fitted.detection.instance_id
        fitted.detection.box = mask_box(mask)
    if seen_share(pipeline, piece, view, divided[detection.view]) < MIN_COVERAGE:
        return None   # a part hidden or seen through where it is fitted: not seen (module)
    if not {piece.detection.obj_id, rest.detection.obj_id} & pipeline.flat_ids and (
            same_place(pipeline, piece, rest) or fill_one_space(pipeline, piece, rest)):
        return None   # thick, and the refits put the piece back on the rest's part
    edge = piece.detection.instance_id if is_edge_band(
        divided[detection.view], piece.detection.instance_id, detection.instance_id,
        pipeline.fit_params.edge_band_px) else None
    if edge is not None:   # the part's own blurred edge, left out by its fit (edge_bands.py)
        divided = without_label(divided, edge)
    labels.update(divided)
    job.points, job.candidates = rest.points, rest.candidates
    vars(detection).update(vars(rest.detection))
    return piece if edge is None else None


def touches(mask: np.ndarray, labels: np.ndarray, instances: Sequence[int]) -> bool:
    """Whether ``mask`` (H, W) bool borders (8-connected) or overlaps a region of
    ``instances`` in ``labels``."""
    if not len(instances):
        return False
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return bool(np.isin(labels[grown], instances).any())


def seen_share(pipeline: PerceptionPipeline, job: PartJob, view: ViewInput,
               labels: np.ndarray) -> float:
    """The share of ``job``'s fitted part's silhouette in its view (its model's samples at its
    pose, :func:`~tlessbot_ros.core.pose.silhouette.silhouette`) that its own region of
    ``labels`` covers: where the silhouette lies on another region or on the table, the part
    would be hidden there (or the table seen through it), so this is the share of it that
    is seen (0 without a pose)."""
    pose = job.detection.pose
    if pose is None or job.detection.obj_id == UNKNOWN_ID:
        return 0.0
    obj = pose_stage(pipeline.pose_estimator).database[job.detection.obj_id]
    points = obj.model_points.astype(np.float64)
    box = window(points, [pose.T_camera_object], view.intrinsics, margin_px=2)
    if box is None:
        return 0.0
    outline = silhouette(points, pose.T_camera_object, view.intrinsics, box,
                         obj.sample_spacing_m())
    if not outline.any():
        return 0.0
    x0, y0, w, h = box
    own = labels[y0:y0 + h, x0:x0 + w] == job.detection.instance_id
    return float(np.count_nonzero(own & outline) / np.count_nonzero(outline))


def reassigned(pipeline: PerceptionPipeline, view: ViewInput, labels: np.ndarray, *jobs: PartJob,
               final: bool = False) -> np.ndarray:
    """``labels`` of the fitted view with each depth pixel of ``jobs``' regions given to the
    one fit that explains it (inside its outline, within ``verify_inlier_m`` of its surface),
    where exactly one does, and each pixel of the regions without depth to the region whose
    claimed pixels lie nearest in the image, as :func:`unexplained_piece` divides them (what
    the depth cannot attribute belongs to the part beside it: a thin part's rim, its dark
    faces); ``jobs``' points follow their regions. ``final`` (the fits are done): the depth
    pixels neither fit explains go to the nearer side too, so that the regions and boxes
    hold every pixel of their parts, and the points stay as the fits saw them (pixels no fit
    explains, given to a side before its refit, can pull that refit off its part)."""
    estimator = pose_stage(pipeline.pose_estimator)
    assert view.depth_m is not None
    ids = [job.detection.instance_id for job in jobs]
    region = np.isin(labels, ids)
    box = mask_box(region)
    points, pixels = depth_to_points(view.depth_m, view.intrinsics.K, mask=region, box=box)
    points = points.astype(np.float64)
    explains = []
    for job in jobs:
        pose = job.detection.pose
        assert pose is not None
        explains.append(explained(points, estimator.database[job.detection.obj_id],
                                  pose.T_camera_object, estimator.refiner,
                                  pipeline.fit_params.verify_inlier_m))
    out: np.ndarray = np.array(labels, copy=True)
    x0, y0, w, h = box
    nearest = np.full((len(ids), h, w), np.inf, np.float32)
    for k, instance in enumerate(ids):
        alone = explains[k] & ~np.any([e for j, e in enumerate(explains) if j != k], axis=0)
        out[pixels[alone, 0], pixels[alone, 1]] = instance
        claimed = np.ones((h, w), np.uint8)
        claimed[pixels[alone, 0] - y0, pixels[alone, 1] - x0] = 0
        if not claimed.all():
            nearest[k] = cv2.distanceTransform(claimed, cv2.DIST_L2, 3)
    blind = region[y0:y0 + h, x0:x0 + w].copy()   # without depth (final: or no fit's)
    attributed = np.any(explains, axis=0) | (not final)
    blind[pixels[attributed, 0] - y0, pixels[attributed, 1] - x0] = False
    if np.isfinite(nearest).any(axis=(1, 2)).all():   # every side claims pixels
        side = np.asarray(ids)[np.argmin(nearest, axis=0)]
        out[y0:y0 + h, x0:x0 + w][blind] = side[blind]
    for job in [] if final else jobs:
        mask = out == job.detection.instance_id
        job.points = roi_cloud(view.depth_m, mask, view.intrinsics, box=mask_box(mask))
        job.detection.n_points = len(job.points)
    return out


def divided_job(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                labels: dict[str, np.ndarray], instance: int) -> PartJob | None:
    """One side of a divided region (``instance`` in ``labels``), classified
    (:func:`piece_candidates`) and fitted in ``job``'s view and table frame; None when it
    has too few depth points or no candidate."""
    name = job.detection.view
    view = views[name]
    assert view.depth_m is not None
    mask = labels[name] == instance
    box = mask_box(mask)
    points = roi_cloud(view.depth_m, mask, view.intrinsics, box=box)
    candidates = piece_candidates(pipeline, views, labels, instance, job.candidates
                                  if instance == job.detection.instance_id else None)
    if not candidates or len(points) < pipeline.fit_params.min_roi_points or \
            (instance != job.detection.instance_id and not raised(pipeline, points, job)):
        return None
    side = PartJob(Detection(instance, candidates[0], name, box), points, candidates,
                   job.T_world_camera)
    side.detection.n_points = len(points)
    pipeline.fit_part(side)
    return side


def raised(pipeline: PerceptionPipeline, points: np.ndarray, job: PartJob) -> bool:
    """Whether ``points`` (``job``'s view) stand above the table by at least half the thinnest
    known part's thickness (median height): a part lying on the table has its points that
    high, the table seen through a region's gaps has them at 0."""
    extents = pose_stage(pipeline.pose_estimator).database.extents_m()
    if extents is None or job.T_world_camera is None or not len(points):
        return False
    height = float(np.median(transform_points(job.T_world_camera, points)[:, 2]))
    return height >= 0.5 * float(extents.min())


def fits_alone(pipeline: PerceptionPipeline, job: PartJob) -> bool:
    """Whether ``job``'s fit makes it a part: it passes the unknown rule on its points, and
    its points cover at least ``unknown_below_cover`` of the fitted model's surface that
    faces the camera, :data:`MIN_COVERAGE` (a sliver of a part fitted as a larger one does
    not)."""
    estimator = pose_stage(pipeline.pose_estimator)
    p = pipeline.fit_params
    pose = job.detection.pose
    if pose is None or job.detection.obj_id == UNKNOWN_ID or pose.coverage < MIN_COVERAGE:
        return False
    share, covered = outline_shares(p, job.points, job.detection.obj_id, pose, estimator)
    return share >= p.unknown_below_fitness and covered >= p.unknown_below_cover


def apart(pipeline: PerceptionPipeline, a: PartJob, b: PartJob) -> bool:
    """Whether two fits are two parts: neither explains the other's points as the unknown
    rule reads a part's own (the fragment filter's test, :mod:`tlessbot_ros.core.one_part`):
    one part's two pieces fitted alone each fit the whole part, over the other piece too."""
    estimator = pose_stage(pipeline.pose_estimator)
    p = pipeline.fit_params
    for fitted, other in ((a, b), (b, a)):
        pose = fitted.detection.pose
        assert pose is not None
        share, covered = outline_shares(p, other.points, fitted.detection.obj_id, pose,
                                        estimator)
        if share >= p.unknown_below_fitness and covered >= p.unknown_below_cover:
            return False
    return True


def fill_one_space(pipeline: PerceptionPipeline, a: PartJob, b: PartJob) -> bool:
    """Whether either fitted model has ``FitParams.same_part_share`` of its surface samples
    inside the other (:func:`~tlessbot_ros.core.same_part.shared_share`): two rigid parts
    cannot, so the piece is a part of the rest's, left out by a fit a little off (a thick
    part's piece, which the depth's seams do not bound)."""
    share = pipeline.fit_params.same_part_share
    if share <= 0:
        return False
    shares = shared_shares(pose_stage(pipeline.pose_estimator).database, a, b)
    return shares is not None and max(shares) >= share


def same_place(pipeline: PerceptionPipeline, a: PartJob, b: PartJob) -> bool:
    """Whether two fitted parts' centres (in the table frame, or one camera's) lie within
    ``fragment_overlap`` of the smaller diameter: one part fitted twice
    (:mod:`tlessbot_ros.core.fragments`)."""
    centres = []
    for job in (a, b):
        pose = job.detection.pose
        if pose is None or job.detection.obj_id == UNKNOWN_ID:
            return False
        T = np.eye(4) if job.T_world_camera is None else job.T_world_camera
        centres.append(transform_points(T, pose.T_camera_object[None, :3, 3])[0])
    if (a.T_world_camera is None or b.T_world_camera is None) and \
            a.detection.view != b.detection.view:
        return False
    database = pose_stage(pipeline.pose_estimator).database
    diameter = min(database[a.detection.obj_id].diameter_m,
                   database[b.detection.obj_id].diameter_m)
    gap = np.linalg.norm(centres[0] - centres[1])
    return bool(gap < pipeline.fit_params.fragment_overlap * diameter)


def piece_candidates(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
                     labels: dict[str, np.ndarray], instance: int,
                     before: tuple[int, ...] | None = None) -> tuple[int, ...]:
    """The classes to fit to one side of a divided region: the classifier's candidates for
    its crops where the pipeline has a classifier and the views colour; else (the pose node)
    ``before``, the region's own candidates, or every known part (ranked by their fit,
    :func:`~tlessbot_ros.core.part_fit.fit_part`)."""
    database = pose_stage(pipeline.pose_estimator).database
    rgb = {name: view.rgb for name, view in views.items() if view.rgb is not None}
    if pipeline.classifier is not None and rgb:
        alone = {name: np.where(image == instance, image, 0).astype(image.dtype)
                 for name, image in labels.items() if name in rgb}
        guess = pipeline.classify(rgb, alone, views=views).get(instance)
        return () if guess is None else tuple(c for c in guess.candidates if c in database)
    return before if before is not None else tuple(sorted(database.objects))


__all__ = ['MIN_COVERAGE', 'apart', 'divided_job', 'explained', 'fits_alone',
           'piece_candidates', 'piece_in_views', 'raised', 'reassigned', 'same_place',
           'seen_share', 'split_off', 'split_then', 'touches', 'unexplained_piece']
