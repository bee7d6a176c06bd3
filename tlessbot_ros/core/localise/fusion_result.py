"""What the fusion of the two views (:mod:`.two_view`) is tuned with and gives: the instances
with one id in both views."""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tlessbot_ros.core.localise.instances import boxes_from_labels

FUSION_METHODS = ('side_only', 'algorithm1', 'calibrated')


@dataclass(frozen=True)
class FusionParams:
    """Tuning of :func:`fuse_views`.

    Attributes:
        method: one of ``FUSION_METHODS``.
        prism_height_m: height of the prism a top blob is lifted to when there is no top depth.
        min_height_m: lifted points lower than this above the table are table (ignored).
        max_height_m: lifted points higher than this are noise (ignored).
        pixel_step: use every n-th pixel of a top blob when lifting it (speed).
        min_overlap_px: smallest overlap (pixels) of a predicted region with a side blob for a
            match.
        min_overlap_fraction: ... and as a fraction of the predicted visible region.
        min_visible_px: a prediction with fewer visible side pixels than this is treated as
            occluded in the side view.
        seed_erode_px: predicted regions are eroded by this radius before seeding the split, px (>=
            0).
        fragment_fraction: a side blob matching no prediction by the rules above but lying
            at least this much inside one joins it (fragments of one part share its id).
        drop_unpredicted: drop side blobs that no top blob predicts (fewer false positives
            when the top view sees the whole work area; off by default).
        keep_depth_splits: a side blob that one top blob predicts but that the side depth divided
            keeps its pieces apart (new ids).
        keep_thin_beside_tall: ... and so does one whose side segmentation holds a thin part
            (:mod:`.thin`) beside a part that is not.
        thin_join_colour_floors: top blobs over one thin side instance are fragments of one
            part unless their side colours differ by more than this many colour floors (0: off).
        thin_join_pieces: ... over a piece of a side blob that is one thin side instance too
            (a plate against a taller part, kept apart from it), where that piece fits a part.
        thin_join_fit: a piece fits a part where its outline on the table is within this many
            times the part's two largest extents (>= 1; ``fits_a_part``).
        part_footprints_m: per part its two largest extents (m), set by the pipeline from the
            parts' sizes; None: unknown, no piece joined (no ROS parameter).
        keep_apart_by_prediction: two side instances of one blob that the top view's
            predictions give to two of its blobs stay apart.
        whole_pieces_apart: a piece of a side blob that no top blob takes and that could be a
            whole part is a part of its own beside several top blobs too, as beside one.
        table_divides: side blobs that one top blob predicts get ids of their own where
            every path between them in the side image crosses the table seen (:mod:`.table_gap`).
        gap_table_floors: a fused side region is divided along a gap within this many colour
            floors of the table where the views' own regions have two parts (0: off).
        gap_band_px: the widest such gap, as the radius of a disc (px, >= 1).
        gap_side_instances: two side instances count as two parts there, as two top blobs do.
        lightness_top_ratio: a side blob's lightness halves stay apart only where the top
            view's blobs over it hold two lightnesses this many times apart (0: no check).
        apart_longer_than_parts: two side instances of one blob stay apart where together
            they lie longer on the table than this many times the longest part (0: off).
        apart_each_whole: ... and where each holds this many times the pixels of the smallest
            whole part as long as it looks (:mod:`.part_scale`; 0: off).
        whole_cut_border: ... but not where they meet along this many times the square root of
            the smaller's pixels: one part cut across (``shared_border_ratio``; 0: off).
        box_margin_px: Algorithm 1: tolerance when testing whether a carried foot point lies
            in a side box.
    """

    method: str = 'calibrated'
    prism_height_m: float = 0.03
    min_height_m: float = 0.003
    max_height_m: float = 0.30
    pixel_step: int = 2
    min_overlap_px: int = 40
    min_overlap_fraction: float = 0.15
    min_visible_px: int = 40
    seed_erode_px: int = 2
    box_margin_px: int = 6
    fragment_fraction: float = 0.5
    drop_unpredicted: bool = False
    keep_depth_splits: bool = True
    keep_thin_beside_tall: bool = True
    thin_join_colour_floors: float = 2.0
    thin_join_pieces: bool = True
    thin_join_fit: float = 1.2
    part_footprints_m: tuple[tuple[float, float], ...] | None = None
    keep_apart_by_prediction: bool = True
    whole_pieces_apart: bool = True
    table_divides: bool = True
    gap_table_floors: float = 2.0
    gap_band_px: int = 4
    gap_side_instances: bool = True
    lightness_top_ratio: float = 2.0
    apart_longer_than_parts: float = 1.1
    apart_each_whole: float = 1.0
    whole_cut_border: float = 1.5

    def with_parts(self, extents_m: np.ndarray | None) -> FusionParams:
        """These params with ``part_footprints_m`` from the parts' (N, 3) box extents (m);
        as they are without the extents or where the footprints are set."""
        if extents_m is None or self.part_footprints_m is not None:
            return self
        largest = -np.sort(-np.abs(np.asarray(extents_m, float).reshape(-1, 3)), axis=1)
        return replace(self, part_footprints_m=tuple(
            (float(a), float(b)) for a, b in largest[:, :2]))

    def __post_init__(self) -> None:
        if self.method not in FUSION_METHODS:
            raise ValueError(f'method must be one of {FUSION_METHODS}, got {self.method!r}')
        if self.pixel_step < 1:
            raise ValueError(f'pixel_step must be >= 1, got {self.pixel_step}')
        if self.thin_join_colour_floors < 0:
            raise ValueError('thin_join_colour_floors must be >= 0 (0: off), got '
                             f'{self.thin_join_colour_floors}')
        if self.thin_join_fit < 1:
            raise ValueError(f'thin_join_fit must be >= 1, got {self.thin_join_fit}')
        if self.gap_table_floors < 0 or self.gap_band_px < 1:
            raise ValueError('gap_table_floors must be >= 0 and gap_band_px >= 1, got '
                             f'{self.gap_table_floors} and {self.gap_band_px}')
        if self.apart_longer_than_parts != 0 and self.apart_longer_than_parts < 1:
            raise ValueError('apart_longer_than_parts must be 0 (off) or at least 1, got '
                             f'{self.apart_longer_than_parts}')
        if self.apart_each_whole < 0 or self.whole_cut_border < 0:
            raise ValueError('apart_each_whole and whole_cut_border must be >= 0 (0: off), got '
                             f'{self.apart_each_whole} and {self.whole_cut_border}')
        if not 0.0 <= self.min_overlap_fraction <= 1.0:
            raise ValueError('min_overlap_fraction must be in [0, 1], got '
                             f'{self.min_overlap_fraction}')


@dataclass
class FusedInstance:
    """One object after fusion.

    Attributes:
        instance_id: its id in both label images (1..65535).
        in_top, in_side: whether it has pixels in that view's label image.
        box_top, box_side: (x, y, w, h) int pixels in that view, or None.
        area_top, area_side: pixel counts.
        split: True if its side pixels were cut out of a blob holding several objects.
    """

    instance_id: int
    in_top: bool
    in_side: bool
    box_top: tuple[int, int, int, int] | None = None
    box_side: tuple[int, int, int, int] | None = None
    area_top: int = 0
    area_side: int = 0
    split: bool = False

    @property
    def views(self) -> tuple[str, ...]:
        return tuple(v for v, on in (('top', self.in_top), ('side', self.in_side)) if on)

    @property
    def preferred_view(self) -> str:
        """The view the pose estimator should use: side when visible there, else top."""
        return 'side' if self.in_side else 'top'


@dataclass
class FusionResult:
    """Output of :func:`fuse_views` for one frame pair.

    Attributes:
        labels: {'top': (H, W) uint16, 'side': (H, W) uint16}, 0 = background, one id per
            object shared by both views.
        instances: the objects, sorted by id.
        method: the method used.
        predicted_side: (H, W) uint16 predicted visible side regions (calibrated method only;
            ids as in ``labels``), for inspection.
        timings_ms: wall time per stage.
    """

    labels: dict[str, np.ndarray]
    instances: list[FusedInstance]
    method: str
    predicted_side: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)

    def instance(self, instance_id: int) -> FusedInstance:
        for inst in self.instances:
            if inst.instance_id == instance_id:
                return inst
        raise KeyError(f'no instance {instance_id}')

# --------------------------------------------------------------------------- helpers
def instances_from_labels(top_labels: np.ndarray, side_labels: np.ndarray,
                           split_ids: set[int]) -> list[FusedInstance]:
    n = int(max(top_labels.max(initial=0), side_labels.max(initial=0)))
    if n == 0:
        return []
    tb, ta = boxes_from_labels(top_labels)
    sb, sa = boxes_from_labels(side_labels)
    out = []
    for i in range(1, n + 1):
        at = int(ta[i - 1]) if i <= ta.size else 0
        as_ = int(sa[i - 1]) if i <= sa.size else 0
        if at == 0 and as_ == 0:
            continue
        out.append(FusedInstance(
            instance_id=i, in_top=at > 0, in_side=as_ > 0,
            box_top=_box(tb[i - 1]) if at else None, box_side=_box(sb[i - 1]) if as_ else None,
            area_top=at, area_side=as_, split=i in split_ids))
    return out


def _box(values: np.ndarray) -> tuple[int, int, int, int]:
    x, y, w, h = (int(v) for v in values)
    return x, y, w, h


__all__ = ['FUSION_METHODS', 'FusedInstance', 'FusionParams', 'FusionResult',
           'instances_from_labels']
