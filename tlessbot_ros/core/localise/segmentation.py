"""Colour segmentation of textureless parts on a table: watershed, HED, CIE-LAB, background.

This is the paper's §3.1 (Sensors 2020, "Marker-less 3D object recognition and 6D pose estimation
for homogeneous textureless objects") built from OpenCV operations, so that a view costs
milliseconds (docs/bench/stage-cpu.md). :func:`segment` runs the stages of the sibling modules:

* :mod:`~tlessbot_ros.core.localise.colour`: HED colour deconvolution and CIE-LAB at the cue
  scale, histogram background peaks and trend removal;
* :mod:`~tlessbot_ros.core.localise.cues`: each cue's candidate and sure-object masks (grey
  level, HED, LAB histogram cut-offs, the empty-table difference with its shadow test, and
  the height above the table from depth);
* :mod:`~tlessbot_ros.core.localise.instances`: the watershed that floods from the union of
  the cues, then connected components and touching-object separation.

All images are (H, W, 3) uint8 RGB. Labels are (H, W) uint16 with 0 = background. Boxes are
(x, y, w, h) int32 pixels, the usual OpenCV / BOP ``bbox`` convention.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.localise.colour import check_rgb, rgb_to_lab
from tlessbot_ros.core.localise.colour_edge import drop_blobs_without_colour_edge
from tlessbot_ros.core.localise.cues import (
    COLOUR_CUES,
    BackgroundModel,
    DepthCue,
    background_change,
    downscale,
    eroded,
    opened,
    prepare_background,
    shadow_mask,
    table_height_m,
    view_depth_cue,
)
from tlessbot_ros.core.localise.instances import instances_at_scale, watershed_refine
from tlessbot_ros.core.localise.params import SegmentationParams
from tlessbot_ros.core.localise.part_length import ViewDepth
from tlessbot_ros.core.localise.part_scale import whole_part_px
from tlessbot_ros.core.localise.small_parts import small_blobs_from_depth, table_coloured
from tlessbot_ros.core.localise.thin import thin_instances, thin_lift

if TYPE_CHECKING:
    from tlessbot_ros.core.common import CameraIntrinsics


@dataclass
class Segmentation:
    """Result of :func:`segment` for one view.

    Attributes:
        labels: (H, W) uint16 instance labels, 0 = background, 1..N objects.
        boxes: (N, 4) int32 (x, y, w, h) of instance ``i + 1`` in row ``i``.
        areas: (N,) int64 pixel counts.
        foreground: (H, W) bool union mask before instance separation.
        thin: (N,) bool; thin parts (:mod:`~tlessbot_ros.core.localise.thin`), kept whole.
        whole_parts: (K, 3) per part its largest extent (m), the smallest blob that can be
            it whole and the longest it can look in this view (px)
            (``SegmentationParams.whole_parts``; none: unknown; :meth:`whole_part_px`).
        depth_groups: (N,) int32; instances cut from one piece of a depth split share an id
            > 0 (two parts whose seam the depth shows), 0 = not divided by depth.
        table_seen: (H, W) bool pixels whose own valid depth lies at table height (no
            filter: a gap of a few pixels between two parts shows), None without depth.
        colour_floors: (3,) the colour cues' smallest cut-offs in LAB (``grey_floor``,
            ``lab_floor``, ``lab_floor``): the unit of a colour difference in this view.
        depth: the view's depth and camera, to measure a region on the table
            (:mod:`.part_length`); None without depth, and in a view not split by depth.
        cues: per-method bool candidate masks at ``params.cue_scale`` (for inspection).
        timings_ms: wall time per stage in milliseconds: 'lab' (conversion), 'depth',
            'cue_<method>' per colour cue, 'cues' (the union), 'watershed', 'instances' and
            'total'.
    """

    labels: np.ndarray
    boxes: np.ndarray
    areas: np.ndarray
    foreground: np.ndarray
    depth_groups: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    thin: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    table_seen: np.ndarray | None = None
    whole_parts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colour_floors: np.ndarray = field(default_factory=lambda: _colour_floors(
        SegmentationParams()))
    depth: ViewDepth | None = None
    cues: dict[str, np.ndarray] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(self.boxes.shape[0])

    def whole_part_px(self, height_m: float = 0.0, length_px: float = 0.0) -> float:
        """The smallest blob (px) that can be a whole part ``height_m`` high and
        ``length_px`` long in this view, 0 when the parts are unknown
        (:func:`~tlessbot_ros.core.localise.part_scale.whole_part_px`)."""
        return whole_part_px(self.whole_parts, height_m, length_px)

    @property
    def longest_part_px(self) -> float:
        """The longest a part can look in this view (px; 0: unknown)."""
        return float(self.whole_parts[:, 2].max()) if len(self.whole_parts) else 0.0


class _Stopwatch:
    """Wall time of consecutive stages in milliseconds."""

    def __init__(self) -> None:
        self.start = self.last = time.perf_counter()
        self.ms: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = (now - self.last) * 1e3
        self.last = now

    def total(self) -> dict[str, float]:
        self.ms['total'] = (time.perf_counter() - self.start) * 1e3
        return self.ms


def segment(rgb: np.ndarray, *, background: np.ndarray | BackgroundModel | None = None,
            depth_m: np.ndarray | None = None,
            intrinsics: CameraIntrinsics | np.ndarray | None = None,
            T_world_camera: np.ndarray | None = None, split_by_depth: bool = True,
            params: SegmentationParams = SegmentationParams()) -> Segmentation:
    """Segment the parts on a table in one RGB view (paper §3.1), optionally helped by depth.

    The cues are computed at ``params.cue_scale`` (default half resolution); the watershed
    that places the contours and the instance separation run at full resolution.

    Args:
        rgb: (H, W, 3) uint8 RGB image.
        background: optional empty-table image from the same camera, (H, W, 3) uint8 RGB or a
            :class:`~tlessbot_ros.core.localise.BackgroundModel` from
            :func:`~tlessbot_ros.core.localise.prepare_background` (faster when reused).
            When given, every histogram cut-off is read on the difference to it and the
            'background' cue (LAB distance with shadow test) joins the union.
        depth_m: optional (H, W) float depth in metres aligned to ``rgb`` (0 / NaN invalid).
            With ``intrinsics`` and ``T_world_camera`` it adds the 'depth' cue (not in the
            paper): height above the table plane, see
            :func:`~tlessbot_ros.core.localise.height_above_table`. It is fused
            with the colour cues: high pixels join the union, pixels with valid depth on the
            table plane veto colour candidates (shadows) and seed the watershed's background;
            pixels without valid depth are left to the colour cues.
        intrinsics: :class:`~tlessbot_ros.core.common.CameraIntrinsics` or a (3, 3) K of
            the image (needed with ``depth_m``).
        T_world_camera: (4, 4) camera pose in the table frame (needed with ``depth_m``).
        split_by_depth: with depth, divide blobs whose depth shows the seam of two parts
            (``params.depth_split_jump``); the pipeline does it in the side view only (see
            :meth:`~tlessbot_ros.core.pipeline.PerceptionPipeline.localise`).
        params: see :class:`~tlessbot_ros.core.localise.SegmentationParams`.

    Returns:
        :class:`Segmentation` with uint16 labels (0 = background), (N, 4) boxes and timings.
    """
    watch = _Stopwatch()
    rgb = check_rgb(rgb)
    bgm = _background_for(rgb, background, params)
    if depth_m is not None:
        _check_depth(rgb, depth_m, intrinsics, T_world_camera)
    small = downscale(rgb, params.cue_scale)
    lab = rgb_to_lab(small)
    watch.lap('lab')
    depth_cue = None
    if depth_m is not None and intrinsics is not None and T_world_camera is not None \
            and 'depth' in params.methods:   # (depth without the other two: raised above)
        depth_cue = view_depth_cue(depth_m, intrinsics, T_world_camera, rgb.shape,
                                    small.shape, params, with_surfaces=split_by_depth)
        watch.lap('depth')
    cues, candidate, sure = _union_of_cues(small, lab, bgm, depth_cue, params, watch)
    if params.open_px > 0:
        candidate = opened(candidate, params.open_px)
        sure &= candidate
    candidate = _upscale(candidate, rgb.shape)
    sure = _upscale(sure, rgb.shape)
    table = None if depth_cue is None else _upscale(eroded(depth_cue.table, 1), rgb.shape)
    watch.lap('cues')
    foreground = _foreground(rgb, candidate, sure, table, depth_cue, params)
    watch.lap('watershed')
    labels, boxes, areas, groups = instances_at_scale(
        foreground, rgb, small, params,
        surfaces=None if depth_cue is None or not split_by_depth else depth_cue.surfaces,
        height_m=None if depth_cue is None else depth_cue.height_m,
        thin_regions=None if depth_cue is None or not split_by_depth
        else depth_cue.thin_regions)   # from the top a thin part reads small: no region
    if split_by_depth:   # the nearer view: a part a few pixels across, completed by depth
        boxes, areas = _small_blobs_by_depth(labels, boxes, areas, depth_m, intrinsics,
                                             T_world_camera, depth_cue, params, rgb)
    thin = thin_instances(labels, None if depth_cue is None else depth_cue.height_m, params)
    watch.lap('instances')
    return Segmentation(labels=labels, boxes=boxes, areas=areas, foreground=foreground,
                        depth_groups=groups, thin=thin, cues=cues, timings_ms=watch.total(),
                        table_seen=_table_seen(depth_cue, params, rgb.shape),
                        whole_parts=np.array(params.whole_parts or (), float).reshape(-1, 3),
                        colour_floors=_colour_floors(params),
                        depth=_view_depth(depth_m, intrinsics, T_world_camera, params)
                        if split_by_depth and depth_cue is not None else None)


def _view_depth(depth_m: np.ndarray | None, intrinsics: CameraIntrinsics | np.ndarray | None,
                T_world_camera: np.ndarray | None, params: SegmentationParams
                ) -> ViewDepth | None:
    """The view's :class:`~.part_length.ViewDepth` (None without depth or camera)."""
    if depth_m is None or intrinsics is None or T_world_camera is None:
        return None
    return ViewDepth(depth_m, np.asarray(getattr(intrinsics, 'K', intrinsics), np.float64),
                     np.asarray(T_world_camera, np.float64), params.depth_min_height_m)


def _colour_floors(params: SegmentationParams) -> np.ndarray:
    """(3,) float32 (``grey_floor``, ``lab_floor``, ``lab_floor``) of ``params``."""
    return np.array([params.grey_floor, params.lab_floor, params.lab_floor], np.float32)


def _foreground(rgb: np.ndarray, candidate: np.ndarray, sure: np.ndarray,
                table: np.ndarray | None, depth_cue: DepthCue | None,
                params: SegmentationParams) -> np.ndarray:
    """The (H, W) bool union mask from the full-resolution candidates and sure markers: the
    watershed's (``table``: its sure background), small blobs whole, and without the colour
    pieces of a patterned table that the depth let through (:mod:`.colour_edge`)."""
    if 'watershed' in params.methods:
        foreground = watershed_refine(rgb, candidate, eroded(sure, 1), band_px=params.band_px,
                                      sure_background=table)
        foreground = _blobs_the_watershed_lost(foreground, candidate, params.watershed_keep_share)
    else:
        foreground = candidate
    if params.small_blob_candidates_px > 0:
        foreground = _small_blobs_whole(foreground, candidate, params.small_blob_candidates_px,
                                        rgb, _trim_floors(params))
    if depth_cue is not None:
        foreground = drop_blobs_without_colour_edge(
            foreground, rgb, _upscale(depth_cue.candidate, rgb.shape),
            _upscale(depth_cue.table, rgb.shape), params)
    return foreground


def _table_seen(depth_cue: DepthCue | None, params: SegmentationParams,
                shape: tuple[int, ...]) -> np.ndarray | None:
    """(H, W) bool: the pixels whose own valid depth (no filter) lies at table height
    (:func:`~tlessbot_ros.core.localise.cues.table_height_m`), None without depth."""
    if depth_cue is None or depth_cue.height_m is None:
        return None
    height = np.nan_to_num(depth_cue.height_m, nan=np.inf)
    return _upscale(height < table_height_m(params, depth_cue.sigma_m), shape)


def _small_blobs_by_depth(labels: np.ndarray, boxes: np.ndarray, areas: np.ndarray,
                          depth_m: np.ndarray | None,
                          intrinsics: CameraIntrinsics | np.ndarray | None,
                          T_world_camera: np.ndarray | None, depth_cue: DepthCue | None,
                          params: SegmentationParams, rgb: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~tlessbot_ros.core.localise.small_parts.small_blobs_from_depth` where the
    view has depth and the parts' sizes admit small blobs; the boxes and areas."""
    if depth_cue is None or depth_m is None or T_world_camera is None or \
            params.small_blob_candidates_px <= 0:
        return boxes, areas
    return small_blobs_from_depth(
        labels, boxes, areas, depth_m, np.asarray(getattr(intrinsics, 'K', intrinsics)),
        T_world_camera, params.small_blob_candidates_px,
        table_height_m(params, depth_cue.sigma_m), int(np.ceil(1 / params.cue_scale)),
        rgb=rgb, floors=_trim_floors(params))


def _background_for(rgb: np.ndarray, background: np.ndarray | BackgroundModel | None,
                    params: SegmentationParams) -> BackgroundModel | None:
    """The empty-table model of ``rgb``'s camera at ``params.cue_scale`` (None: no image)."""
    if background is None:
        return None
    bgm = background if isinstance(background, BackgroundModel) else \
        prepare_background(background, params=params)
    if bgm.rgb.shape != rgb.shape:
        raise ValueError(f'background shape {bgm.rgb.shape} differs from image shape '
                         f'{rgb.shape}; it must come from the same camera and resolution')
    if bgm.scale != params.cue_scale:
        bgm = prepare_background(bgm.rgb, params=params)
    return bgm


def _check_depth(rgb: np.ndarray, depth_m: np.ndarray,
                 intrinsics: CameraIntrinsics | np.ndarray | None,
                 T_world_camera: np.ndarray | None) -> None:
    if intrinsics is None or T_world_camera is None:
        raise ValueError('depth_m needs intrinsics= and T_world_camera= (the camera pose '
                         'in the table frame) to find the table plane')
    if np.shape(depth_m) != rgb.shape[:2]:
        raise ValueError(f'depth_m shape {np.shape(depth_m)} differs from the image '
                         f'{rgb.shape[:2]}; align depth to colour first')


def _union_of_cues(small: np.ndarray, lab: np.ndarray, bgm: BackgroundModel | None,
                   depth_cue: DepthCue | None, params: SegmentationParams,
                   watch: _Stopwatch) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Each cue of ``params.methods`` at the cue scale: ({method: candidates}, union of the
    candidates, union of the sure-object masks)."""
    # Pixels where colour evidence is not trusted: cast shadows, and table seen by depth.
    shadow = None if bgm is None else shadow_mask(lab, bgm.lab, params)
    masks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, cue in COLOUR_CUES:
        if name in params.methods:
            masks[name] = cue(small, lab, bgm, params)
            watch.lap(f'cue_{name}')
    if depth_cue is not None and masks:   # a thin part's pixels at table height stay (thin.py)
        lifted, depth_cue.thin_regions = thin_lift(
            np.logical_or.reduce([c for c, _ in masks.values()]), depth_cue.height_m,
            depth_cue.table, params, noise_m=depth_cue.sigma_m, lab=lab)
        depth_cue.table &= ~lifted
    veto = shadow
    if depth_cue is not None:
        veto = depth_cue.table if veto is None else veto | depth_cue.table
    if veto is not None:
        for cand, sure in masks.values():
            cand &= ~veto
            sure &= ~veto
    if 'background' in params.methods and bgm is not None:
        cand = background_change(lab, bgm.lab, params, shadow=shadow)
        if depth_cue is not None:
            cand &= ~depth_cue.table
        masks['background'] = cand, eroded(cand, 1)
    if depth_cue is not None:
        masks['depth'] = depth_cue.candidate, inner_markers(depth_cue.sure,
                                                            params.depth_sure_erode_px)
    candidate = np.zeros(small.shape[:2], bool)
    sure = np.zeros(small.shape[:2], bool)
    for cand, sure_cue in masks.values():
        candidate |= cand
        sure |= sure_cue
    return {name: cand for name, (cand, _) in masks.items()}, candidate, sure


def inner_markers(sure: np.ndarray, radius: int) -> np.ndarray:
    """``sure`` eroded by ``radius`` px, but each blob that the erosion would remove kept
    whole: a stereo-like depth raises the table a pixel or two beyond a part's outline, and
    sure markers there would hold the watershed's outline off the part's colour edge."""
    if radius <= 0 or not sure.any():
        return sure
    inner = eroded(sure, radius)
    count, blobs = cv2.connectedComponents(sure.view(np.uint8), connectivity=8)
    kept = np.bincount(blobs[inner], minlength=count) > 0
    markers: np.ndarray = inner | (sure & ~kept[blobs])
    return markers


def _trim_floors(params: SegmentationParams) -> np.ndarray | None:
    """The LAB tolerance within which a pixel a small blob grows over has the table's colour
    (``small_blob_trim_floors`` x the colour cues' floors), None when that is off."""
    if params.small_blob_trim_floors <= 0:
        return None
    return params.small_blob_trim_floors * _colour_floors(params)


def _small_blobs_whole(foreground: np.ndarray, candidate: np.ndarray, below_px: int,
                       rgb: np.ndarray | None = None, floors: np.ndarray | None = None
                       ) -> np.ndarray:
    """``foreground`` with every blob of fewer than ``below_px`` pixels grown to the
    candidates it lies on: the watershed puts a contour on the strongest edge near it, and
    on a part a few pixels across that is often inside the part (its lit face against its
    shaded side), which cuts it to its lit face. With ``rgb`` and ``floors`` (LAB), a grown
    pixel with the table's colour around the candidates (:func:`table_coloured`) is not
    kept: the cue scale's blocks and a smoothed depth reach a pixel or two past the part."""
    n, blobs, stats, _ = cv2.connectedComponentsWithStats(foreground.view(np.uint8),
                                                          connectivity=8)
    small = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] < below_px) + 1
    if small.size == 0:
        return foreground
    _, pieces, boxes, _ = cv2.connectedComponentsWithStats(candidate.view(np.uint8),
                                                           connectivity=8)
    under = np.unique(pieces[np.isin(blobs, small) & candidate])
    under = under[under > 0]
    if rgb is None or floors is None:
        grown_all: np.ndarray = foreground | np.isin(pieces, under)
        return grown_all
    out: np.ndarray = foreground.copy()
    H, W = foreground.shape
    for piece in under:   # in the piece's box grown by the band table_coloured reads
        x, y, w, h = (int(v) for v in boxes[piece, :4])
        y0, y1, x0, x1 = max(y - 3, 0), min(y + h + 3, H), max(x - 3, 0), min(x + w + 3, W)
        grown = pieces[y0:y1, x0:x1] == piece
        added = grown & ~foreground[y0:y1, x0:x1]
        if added.any():
            lab = rgb_to_lab(rgb[y0:y1, x0:x1]).astype(np.float32)
            out[y0:y1, x0:x1] |= added & ~table_coloured(lab, grown, floors)
    return out


def _blobs_the_watershed_lost(foreground: np.ndarray, candidate: np.ndarray,
                              keep_share: float) -> np.ndarray:
    """``foreground`` with every candidate blob of which it keeps less than ``keep_share``
    added whole: the watershed floods from the strongest edges, and a part whose own edges are
    weaker than its surroundings' (white plastic on a light table, no sure marker inside) is
    flooded as table although the colour cues found it. ``keep_share`` 0: unchanged."""
    if keep_share <= 0:
        return foreground
    count, blobs = cv2.connectedComponents(candidate.view(np.uint8), connectivity=8)
    kept = np.bincount(blobs[foreground], minlength=count)
    size = np.bincount(blobs.ravel(), minlength=count)
    lost = np.flatnonzero(kept < keep_share * size)
    lost = lost[lost > 0]
    return foreground | np.isin(blobs, lost) if lost.size else foreground


def _upscale(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    if mask.shape == shape[:2]:
        return mask
    return cv2.resize(mask.view(np.uint8), (shape[1], shape[0]),
                      interpolation=cv2.INTER_NEAREST).astype(bool)
