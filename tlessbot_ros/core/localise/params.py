"""Tuning of the per-view segmentation: :class:`SegmentationParams` and the cue names."""
from __future__ import annotations

from dataclasses import dataclass

METHODS = ('watershed', 'hed', 'lab', 'background', 'depth')


@dataclass(frozen=True)
class SegmentationParams:
    """Tuning of :func:`~tlessbot_ros.core.localise.segment`. Defaults were chosen on simulated
    two-view scenes.

    Attributes:
        methods: cues whose union forms the foreground: any of 'watershed', 'hed', 'lab',
            'background', 'depth'.
        cutoff_sigma: candidate cut-off, in robust standard deviations of the background peak.
        sure_sigma: sure-object marker cut-off (histogram extreme), same unit.
        grey_floor, hed_floor, lab_floor: smallest cut-off distance from the background peak per
            channel (grey: L 0-100, HED: optical density, a/b: LAB).
        hed_dark_level: intensities below this are clamped before the HED logarithm, so the
            noise of near-black pixels does not swamp the stain channels.
        border_fraction: width of the image border the background peak is read from, fraction of
            the image size [0, 0.5); 0: all.
        background_delta_e: LAB distance to the empty-table image above which a pixel differs.
        shadow_ratio: (low, high) brightness ratio to the empty table treated as a cast shadow
            when the chromaticity also stays within ``shadow_chroma``.
        shadow_chroma: largest a/b change (LAB units) of a shadowed table pixel.
        band_px: the watershed decides only within this distance of a candidate pixel.
        min_area_px: blobs smaller than this (pixels) are dropped.
        open_px: radius of the morphological opening that removes thin noise before labelling.
        split_touching: separate touching objects (distance transform + watershed).
        split_core_fraction: distance-transform cores are pixels above this fraction of the
            blob's largest distance; two or more cores mean two or more objects.
        split_min_core_px: cores smaller than this (pixels) are ignored.
        split_min_depth_px: largest distance of a blob (pixels) below which it is never split.
        cue_scale: image scale at which the colour cues are computed (1.0 = full resolution).
        colour_split_delta: a blob with two chroma clusters further apart than this (a / L, b / L,
            x100) is divided first (>= 0; 0: off).
        colour_split_min_share: smallest share of the blob for a colour piece (so specular
            highlights do not become parts).
        lightness_split_ratio: a blob whose two lightness clusters' median L differ by more
            than this factor is divided when each piece could be a whole part (0: off).
        depth_min_height_m: depth cue: pixels whose back-projected point lies higher than
            this above the table plane (world z) are object candidates...
        depth_sure_height_m: ... and higher than this, sure object markers.
        depth_sure_erode_px: the depth's sure markers shrunk by this many cue-scale pixels, a
            blob that would vanish kept whole: the watershed places the outline (0: off).
        depth_noise_k: both heights are raised to this many robust deviations of the table's
            measured height (>= 0).
        depth_table_height_m: pixels with valid depth lower than this over the table are table: no
            colour candidates there, m.
        depth_filter_px: aperture of the median filter on the height map (1 = none).
        depth_vote_valid: depth candidate when most valid pixels of the filter window are high
            (holes abstain); False: holes count as table.
        depth_split_jump: a blob whose solid pixels split into pieces at depth jumps above this
            fraction of the depth is divided (>= 0; 0: off).
        depth_split_min_px: smallest solid piece (full-resolution pixels) that counts as a
            part for that split.
        depth_split_step: pieces with no table between them are kept apart at a depth step above
            this fraction of the depth (>= 0; 0: never).
        thin_max_height_m: a blob lower than this above the table (its ``thin_quantile``) is a
            thin part, kept whole, m (>= 0; 0: off).
        thin_quantile: the quantile of a blob's valid heights compared (0..1).
        thin_min_valid: share of a blob's pixels with depth needed to call it thin (0..1).
        thin_lift_height_m: a colour blob that is thin and whose median height reaches this is
            not vetoed by the depth's table pixels: its top lies in the noise, m (0: off).
        thin_lift_min_share: ... where those table pixels take at least this share of its
            inside (0..1).
        thin_lift_resolved_k: ... but for its pixels this many table-noise deviations below
            its median height: the depth sees them lower than the part (>= 0; 0: off).
        thin_lift_colour_floors: ... and a blob not lifted whole is tried per colour region (less
            its tall pixels): neighbours within this many colour floors (>= 0; 0: off).
        thin_lift_table_floors: ... but not a region within this many colour floors of one of
            the table's common colours: a piece of the table (>= 0).
        thin_region_cut_border: a lifted region is a part of its own in its blob where it meets
            the rest along less than this x sqrt(smaller's px) (more: one part's flange; >= 0).
        thin_region_no_bridge: ... nor a region touching two pieces the veto leaves that could
            each be a whole part: the band between two parts in a pile (bool).
        watershed_keep_share: a candidate blob of which the watershed keeps less than this
            share is kept whole (a part with weaker edges than its surroundings; 0..1, 0: off).
        small_blob_candidates_px: a blob smaller than this (px) keeps its candidates' extent,
            not the watershed's contour (0: off; set where :mod:`.part_scale` lowers sizes).
        small_blob_trim_floors: ... but not the pixels within this many ``grey_floor`` /
            ``lab_floor`` of the table's colour around it (0: off).
        part_area_fraction: with the parts' sizes, a view keeps blobs down to this fraction
            of the smallest part's expected area there, if below ``min_area_px`` (0..1; 0: off).
        part_width_fraction: ... and opens by at most this fraction of the narrowest part's
            expected width, if below ``open_px`` (0..1; 0: off; :mod:`.part_scale`).
        whole_parts: per part (its largest extent in m; the smallest blob that can be it
            whole in this view, ``part_area_fraction`` of its expected area, and the longest
            it can look there, in px), set by :mod:`.part_scale`; None: unknown (no ROS
            parameter).
        largest_part_px_m2: with the parts' sizes, the most image pixels any part can cover
            at 1 m from the camera (its largest outline, :mod:`.part_scale`; at z m: this
            over z squared); a blob larger than that is several parts, thin or not, and is
            divided; None: unknown (no ROS parameter).
        colour_edge_floors: a blob the depth does not find, within this many ``grey_floor`` /
            ``lab_floor`` of the table around it, in a region longer than any part: table (0: off).
        colour_edge_ring_px: width (full-resolution px) of the bands inside and outside a
            blob's outline whose colours that test compares.
        colour_edge_outline_share: a blob the depth does not find, whose colour steps on under
            this share of its outline, in a colour common around it: table (0..1; 0: off).
        colour_edge_pattern_share: a blob the depth does not find, with at least this share of
            its pixels in colours common on the table around it: table (0..1; 0: off).
        colour_edge_blend_px: that share also counts pixels between two common colours within
            this many px of both (a square's blurred edge; 0: off).

    ``methods``: 'watershed' adds the grey-level histogram extremes as markers *and* refines the
    union by flooding (without it the union is used as is); 'background' is used only when an
    empty-table image is given, 'depth' only with an aligned depth image and the camera pose
    (leave 'depth' out for the paper's RGB-only method). The floors stop sensor noise on a
    very plain table from becoming objects. Depth-table pixels also seed the watershed's
    background; invalid depth (0 / NaN) votes for nothing, so the colour cues decide there.
    ``depth_split_jump`` divides where the table shows between two pieces (touching parts; a
    groove of one part breaks its surface too but shows no table); ``depth_split_step`` is off
    by default since a part's own self-occlusion makes small steps in the side view.
    """

    methods: tuple[str, ...] = METHODS
    cutoff_sigma: float = 5.0
    sure_sigma: float = 9.0
    grey_floor: float = 8.0
    hed_floor: float = 0.04
    lab_floor: float = 6.0
    hed_dark_level: int = 10
    border_fraction: float = 0.1
    background_delta_e: float = 12.0
    shadow_ratio: tuple[float, float] = (0.3, 0.97)
    shadow_chroma: float = 4.0
    band_px: int = 4
    min_area_px: int = 80
    open_px: int = 1
    split_touching: bool = True
    split_core_fraction: float = 0.55
    split_min_core_px: int = 12
    split_min_depth_px: float = 5.0
    cue_scale: float = 0.5
    colour_split_delta: float = 25.0
    colour_split_min_share: float = 0.12
    lightness_split_ratio: float = 8.0
    depth_min_height_m: float = 0.004
    depth_sure_height_m: float = 0.010
    depth_sure_erode_px: int = 0
    depth_noise_k: float = 4.0
    depth_table_height_m: float = 0.0025
    depth_filter_px: int = 3
    depth_vote_valid: bool = True
    depth_split_jump: float = 0.02
    depth_split_min_px: int = 200
    depth_split_step: float = 0.0
    thin_max_height_m: float = 0.008
    thin_quantile: float = 0.75
    thin_min_valid: float = 0.3
    thin_lift_height_m: float = 0.0015
    thin_lift_min_share: float = 0.1
    thin_lift_resolved_k: float = 2.0
    thin_lift_colour_floors: float = 0.0
    thin_lift_table_floors: float = 2.0
    thin_region_cut_border: float = 1.5
    thin_region_no_bridge: bool = True
    watershed_keep_share: float = 0.0
    small_blob_candidates_px: int = 0
    small_blob_trim_floors: float = 1.0
    part_area_fraction: float = 0.5
    part_width_fraction: float = 0.5
    whole_parts: tuple[tuple[float, float, float], ...] | None = None
    largest_part_px_m2: float | None = None
    colour_edge_floors: float = 1.0
    colour_edge_ring_px: int = 4
    colour_edge_outline_share: float = 0.5
    colour_edge_pattern_share: float = 0.7
    colour_edge_blend_px: int = 2

    def __post_init__(self) -> None:
        if self.thin_max_height_m < 0 or not 0.0 <= self.thin_quantile <= 1.0 or \
                not 0.0 <= self.thin_min_valid <= 1.0:
            raise ValueError('need thin_max_height_m >= 0 (0: off) and thin_quantile, '
                             f'thin_min_valid in 0..1, got {self.thin_max_height_m}, '
                             f'{self.thin_quantile}, {self.thin_min_valid}')
        if self.thin_lift_height_m < 0 or not 0.0 <= self.thin_lift_min_share <= 1.0 or \
                min(self.thin_lift_resolved_k, self.thin_lift_colour_floors,
                    self.thin_lift_table_floors, self.thin_region_cut_border) < 0:
            raise ValueError('need thin_lift_height_m >= 0 m (0: off), thin_lift_min_share '
                             'in 0..1, thin_lift_resolved_k, thin_lift_colour_floors, '
                             'thin_lift_table_floors and thin_region_cut_border >= 0, got '
                             f'{self.thin_lift_height_m}, {self.thin_lift_min_share}, '
                             f'{self.thin_lift_resolved_k}, {self.thin_lift_colour_floors}, '
                             f'{self.thin_lift_table_floors}, {self.thin_region_cut_border}')
        unknown = set(self.methods) - set(METHODS)
        if unknown or not self.methods:
            raise ValueError(f'methods must be a non-empty subset of {METHODS}, '
                             f'got {self.methods}')
        if not 0.0 < self.cutoff_sigma <= self.sure_sigma:
            raise ValueError('need 0 < cutoff_sigma <= sure_sigma, got '
                             f'{self.cutoff_sigma} and {self.sure_sigma}')
        if not (0.0 <= self.part_area_fraction <= 1.0 and 0.0 <= self.part_width_fraction <= 1.0):
            raise ValueError('need part_area_fraction and part_width_fraction in 0..1, got '
                             f'{self.part_area_fraction} and {self.part_width_fraction}')
        if not 0.0 <= self.watershed_keep_share <= 1.0:
            raise ValueError('need watershed_keep_share in 0..1 (0: off), got '
                             f'{self.watershed_keep_share}')
        if self.small_blob_trim_floors < 0 or self.depth_sure_erode_px < 0:
            raise ValueError('need small_blob_trim_floors >= 0 (0: off) and '
                             f'depth_sure_erode_px >= 0, got {self.small_blob_trim_floors} '
                             f'and {self.depth_sure_erode_px}')
        if self.colour_edge_floors < 0 or self.colour_edge_ring_px < 1:
            raise ValueError('need colour_edge_floors >= 0 (0: off) and colour_edge_ring_px '
                             f'>= 1, got {self.colour_edge_floors} and '
                             f'{self.colour_edge_ring_px}')
        if self.lightness_split_ratio != 0 and self.lightness_split_ratio <= 1:
            raise ValueError('lightness_split_ratio must be 0 (off) or above 1, got '
                             f'{self.lightness_split_ratio}')
        if self.colour_edge_blend_px < 0:
            raise ValueError('need colour_edge_blend_px >= 0 (0: off), got '
                             f'{self.colour_edge_blend_px}')
        if not (0.0 <= self.colour_edge_outline_share <= 1.0 and
                0.0 <= self.colour_edge_pattern_share <= 1.0):
            raise ValueError('colour_edge_outline_share and colour_edge_pattern_share must be '
                             f'in [0, 1] (0: off), got {self.colour_edge_outline_share} and '
                             f'{self.colour_edge_pattern_share}')
        if self.min_area_px < 1 or self.small_blob_candidates_px < 0:
            raise ValueError('need min_area_px >= 1 and small_blob_candidates_px >= 0, got '
                             f'{self.min_area_px} and {self.small_blob_candidates_px}')
        if not 0.0 < self.split_core_fraction < 1.0:
            raise ValueError('split_core_fraction must be in (0, 1), got '
                             f'{self.split_core_fraction}')
        if not 0.0 <= self.border_fraction < 0.5:
            raise ValueError(f'border_fraction must be in [0, 0.5), got {self.border_fraction}')
        if not 0.0 < self.cue_scale <= 1.0:
            raise ValueError(f'cue_scale must be in (0, 1], got {self.cue_scale}')
        if not 0.0 < self.depth_min_height_m <= self.depth_sure_height_m:
            raise ValueError('need 0 < depth_min_height_m <= depth_sure_height_m, got '
                             f'{self.depth_min_height_m} and {self.depth_sure_height_m}')
        if self.depth_split_jump < 0 or self.depth_split_step < 0 or \
                self.depth_split_min_px < 1:
            raise ValueError('need depth_split_jump >= 0, depth_split_step >= 0 and '
                             f'depth_split_min_px >= 1, got {self.depth_split_jump}, '
                             f'{self.depth_split_step} and {self.depth_split_min_px}')
        if self.depth_filter_px not in (1, 3, 5):
            raise ValueError(f'depth_filter_px must be 1, 3 or 5, got {self.depth_filter_px}')
        lo, hi = self.shadow_ratio
        if not 0.0 <= lo < hi <= 1.0:
            raise ValueError(f'shadow_ratio must satisfy 0 <= low < high <= 1, got '
                             f'{self.shadow_ratio}')

