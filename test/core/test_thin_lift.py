"""The depth's veto leaves a thin part whole where its top lies in the depth's noise
(``SegmentationParams.thin_lift_height_m``, :func:`~tlessbot_ros.core.localise.thin.
raised_thin_blobs`)."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from tlessbot_ros.core.localise import SegmentationParams, segment
from tlessbot_ros.core.localise.thin import raised_thin_blobs


def _correlated_noise(shape: tuple[int, int], sigma_m: float, blur_px: float,
                      rng: np.random.Generator) -> np.ndarray:
    """Noise spread over ``blur_px`` (a stereo camera's), ``sigma_m`` per pixel."""
    noise = cv2.GaussianBlur(rng.normal(0, 1, shape).astype(np.float32), (0, 0), blur_px)
    return (noise * (sigma_m / noise.std())).astype(np.float32)


def _strip_scene(seed: int = 0):
    """Side view (640x480) of a dark strip 80 x 16 x 3 mm on a light table, its depth spread
    and noisy as a stereo camera's: rgb, depth_m, truth, camera."""
    from tlessbot_ros.core.common import MeshRenderer, default_rig, make_transform
    from tlessbot_ros.sim.shading import table_depth

    cam = default_rig(640, 480)['side']
    v = np.array([[x, y, z] for x in (-0.04, 0.04) for y in (-0.008, 0.008)
                  for z in (0, 0.003)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    renderer = MeshRenderer()
    renderer.add_mesh(v, f, make_transform(np.eye(3), [0.0, 0.0, 0.0]))
    res = renderer.render(cam.intrinsics, cam.T_world_camera)
    truth = res.instance == 0
    h, w = truth.shape
    table_z = table_depth(cam.intrinsics, cam.T_world_camera)
    depth = np.where(truth, res.depth_m, table_z).astype(np.float32)
    rng = np.random.default_rng(seed)
    depth = cv2.GaussianBlur(depth, (0, 0), 3.0)   # the part's step spread to the table
    depth += _correlated_noise(depth.shape, 0.0013, 3.0, rng)
    rgb = np.empty((h, w, 3))
    rgb[:] = (190, 188, 180)
    rgb[truth] = (45, 45, 50)
    rgb = np.clip(rgb + rng.normal(0, 2.0, rgb.shape), 0, 255).astype(np.uint8)
    return rgb, depth, truth, cam


def _best_iou(labels: np.ndarray, truth: np.ndarray) -> float:
    best = 0.0
    for k in range(1, int(labels.max(initial=0)) + 1):
        region = labels == k
        best = max(best, (region & truth).sum() / (region | truth).sum())
    return best


def test_a_thin_strip_in_the_depth_s_noise_is_found_whole() -> None:
    from tlessbot_ros.core.localise.part_scale import view_segmentation

    rgb, depth, truth, cam = _strip_scene()
    args = dict(depth_m=depth, intrinsics=cam.intrinsics, T_world_camera=cam.T_world_camera)
    extents = np.array([[0.08, 0.016, 0.003], [0.044, 0.044, 0.006]])   # a strip, a disc
    params = view_segmentation(SegmentationParams(), extents, cam.intrinsics.K,
                               cam.T_world_camera)
    off = segment(rgb, params=replace(params, thin_lift_height_m=0.0), **args)
    assert _best_iou(off.labels, truth) < 0.6   # the veto cuts it where it reads as table
    seg = segment(rgb, params=params, **args)
    assert seg.count == 1
    assert _best_iou(seg.labels, truth) > 0.8


def test_raised_thin_blobs_keeps_thin_parts_only() -> None:
    rng = np.random.default_rng(3)
    height = rng.normal(0, 0.0013, (60, 90)).astype(np.float32)   # the table, noisy
    candidate = np.zeros(height.shape, bool)
    candidate[5:15, 5:40] = True              # a thin part: 2 mm, many pixels below 2.5 mm
    height[5:15, 5:40] += 0.002
    candidate[30:45, 5:30] = True             # a shadow or a table-coloured piece: 0 mm
    candidate[30:45, 50:80] = True            # a tall part: 30 mm
    height[30:45, 50:80] += 0.03
    candidate[50:58, 50:80] = True            # a thin part without depth
    height[50:58, 50:80] = np.nan
    table = ~np.isnan(height) & (height < 0.0025)   # the veto: many of the thin part's pixels
    params = SegmentationParams(whole_parts=((0.08, 600.0, 80.0),))   # sizes at full scale
    lifted = raised_thin_blobs(candidate, height, table, params)
    assert lifted[6:14, 6:39].all() and not lifted[5, 5:40].any()   # but for its rim
    assert not lifted[30:, :].any() and not lifted[~candidate].any()
    off = SegmentationParams(thin_lift_height_m=0.0)
    assert not raised_thin_blobs(candidate, height, table, off).any()
    assert not raised_thin_blobs(candidate, None, table, params).any()
    resolved = height.copy()
    resolved[5:15, 5:40] = 0.003       # the depth sees all of it: nothing to lift
    assert not raised_thin_blobs(candidate, resolved, resolved < 0.0025, params)[5:15].any()


def test_two_thin_parts_the_table_divides_stay_divided() -> None:
    height = np.zeros((40, 90), np.float32)
    candidate = np.zeros(height.shape, bool)
    candidate[10:30, 5:85] = True      # two plates 3 mm high, touching across a gap of table
    height[10:30, 5:44] = height[10:30, 46:85] = 0.003
    table = height < 0.0025
    lifted = raised_thin_blobs(candidate, height, table, SegmentationParams())
    assert not lifted.any()
    height[10:30, 44:46] = 0.003       # one plate: no gap; a quarter of it reads as table
    height[10:30:2, 5:85:2] = 0.002
    lifted = raised_thin_blobs(candidate, height, height < 0.0025, SegmentationParams())
    assert lifted[11:29, 6:84].all()


def _washer_scene(seed: int):
    """Side view (640x480) of a dark washer 6 mm high, 24 px across with a bore 10 px across,
    on a light table, per-pixel depth (0.9 mm noise): the bore shows its dark wall while the
    depth reads the table there. rgb, depth_m, ring, bore, camera."""
    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.sim.shading import table_depth

    cam = default_rig(640, 480)['side']
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[:480, :640]
    squared = (rows - 240) ** 2 + (cols - 320) ** 2
    bore = squared <= 5 ** 2
    ring = (squared <= 12 ** 2) & ~bore
    tilt = abs(cam.T_world_camera[2, 2])   # the height along the ray, roughly
    depth = table_depth(cam.intrinsics, cam.T_world_camera) - np.where(ring, 0.006 / tilt, 0)
    depth = (depth + rng.normal(0, 0.0009, depth.shape)).astype(np.float32)
    rgb = np.clip(rng.normal(185, 2, (480, 640, 3)), 0, 255)
    rgb[ring | bore] = (45, 45, 50)
    return rgb.astype(np.uint8), depth, ring, bore, cam


def test_a_washer_s_bore_that_reads_table_keeps_the_veto() -> None:
    from tlessbot_ros.core.localise.part_scale import view_segmentation

    for seed in range(2):
        rgb, depth, ring, bore, cam = _washer_scene(seed)
        args = dict(depth_m=depth, intrinsics=cam.intrinsics, T_world_camera=cam.T_world_camera)
        params = view_segmentation(SegmentationParams(), np.array([[0.016, 0.016, 0.006]]),
                                   cam.intrinsics.K, cam.T_world_camera)
        seg = segment(rgb, params=params, **args)
        assert seg.count == 1 and np.mean(seg.labels[ring] > 0) > 0.8
        assert np.mean(seg.labels[bore] > 0) < 0.2   # as without the lift
        every = segment(rgb, params=replace(params, thin_lift_resolved_k=0.0), **args)
        assert np.mean(every.labels[bore] > 0) > 0.8   # the lift took the bore in


def test_only_pixels_the_depth_resolves_below_the_part_keep_the_veto() -> None:
    rng = np.random.default_rng(5)
    height = rng.normal(0, 0.0009, (40, 60)).astype(np.float32)
    candidate = np.zeros(height.shape, bool)
    candidate[10:30, 10:30] = True          # a part 3.5 mm high with a bore reading table
    height[10:30, 10:30] += 0.0035
    height[17:23, 17:23] -= 0.0035
    candidate[10:30, 40:56] = True          # a strip 2 mm high: its low pixels in the noise
    height[10:30, 40:56] += 0.002
    table = height < 0.0025
    params = SegmentationParams(whole_parts=((0.08, 600.0, 80.0),))   # sizes at full scale
    lifted = raised_thin_blobs(candidate, height, table, params, noise_m=0.0009)
    part = np.zeros(height.shape, bool)
    part[11:29, 11:29] = True   # its inside, but for the bore
    part[17:23, 17:23] = False
    assert not lifted[17:23, 17:23].any() and lifted[part].mean() > 0.95
    assert lifted[11:29, 41:55].mean() > 0.95
    for off in (replace(params, thin_lift_resolved_k=0.0), None):   # the rule off; no noise
        every = raised_thin_blobs(candidate, height, table, off or params,
                                  noise_m=0.0009 if off else 0.0)
        assert every[11:29, 11:29].all() and every[11:29, 41:55].all()
    # a part that stands clear of the noise but for its bore: no table pixel left to lift
    height[10:30, 10:30] += 0.002
    height[17:23, 17:23] -= 0.002
    table = height < 0.0025
    lifted = raised_thin_blobs(candidate, height, table, params, noise_m=0.0009)
    assert table[17:23, 17:23].all() and not (lifted & table)[:, :30].any()


def _lab(shape: tuple[int, int], colour: tuple[float, float, float], seed: int = 0
         ) -> np.ndarray:
    """(h, w, 3) float32 LAB of one colour with a little sensor noise (about 0.5 per channel)."""
    rng = np.random.default_rng(seed)
    return (np.array(colour, np.float32) + rng.normal(0, 0.5, shape + (3,))).astype(np.float32)


def test_a_thin_part_in_a_blob_with_a_taller_one_is_lifted_by_its_colour() -> None:
    height = np.zeros((40, 90), np.float32)
    lab = _lab(height.shape, (70.0, 0.0, 0.0))              # a grey table
    candidate = np.zeros(height.shape, bool)
    candidate[10:18, 5:60] = True                           # a blue strip 3 mm high...
    height[10:18, 5:60] = 0.003
    height[10:18:2, 5:60:2] = 0.001                         # ... a quarter of it read as table
    lab[10:18, 5:60] = (45.0, 10.0, -45.0)
    candidate[5:30, 60:85] = True                           # a black block 30 mm high against it
    height[5:30, 60:85] = 0.03
    lab[5:30, 60:85] = (20.0, 0.0, 0.0)
    candidate[30:38, 60:85] = True                          # the table's colour at its foot,
    height[30:38, 60:85] = 0.003                            # raised by the noise
    height[30:38:2, 60:85:2] = 0.001
    lab[30:38, 60:85] = (64.0, 1.0, 1.0)
    table = height < 0.0025
    params = SegmentationParams(thin_lift_colour_floors=1.0)
    assert not raised_thin_blobs(candidate, height, table, params).any()   # no colour: as a blob
    lifted = raised_thin_blobs(candidate, height, table, params, lab=lab)
    assert lifted[11:17, 6:58].all() and not lifted[:, 59:].any()
    noisy = raised_thin_blobs(candidate, height, table, params, lab=lab, noise_m=0.004)
    assert not noisy.any()             # a noise of 4 mm raises a region of that size as high
    for off in (SegmentationParams(), replace(params, thin_lift_colour_floors=0.0)):
        assert not raised_thin_blobs(candidate, height, table, off, lab=lab).any()  # main's


def test_a_thin_part_on_a_patterned_table_is_lifted_alone() -> None:
    rows, cols = np.mgrid[0:60, 0:80]
    checker = ((rows // 12 + cols // 12) % 2).astype(np.float32)
    lab = _lab((60, 80), (0.0, 0.0, 0.0))
    lab[..., 0] += 40.0 + 45.0 * checker                    # light and dark squares
    candidate = np.ones((60, 80), bool)                     # the colour cues take every square
    height = np.zeros((60, 80), np.float32)
    height[20:36, 20:50] = 0.003                            # a pink plate 3 mm high
    height[20:36:2, 20:50:2] = 0.001
    lab[20:36, 20:50] = (60.0, 45.0, 0.0)
    height[48:60, 0:12] = 0.003                             # a square the noise raises
    height[48:60:2, 0:12:2] = 0.001
    table = height < 0.0025
    params = SegmentationParams(thin_lift_colour_floors=1.0)
    assert not raised_thin_blobs(candidate, height, table, params).any()
    lifted = raised_thin_blobs(candidate, height, table, params, lab=lab)
    assert lifted[21:35, 21:49].all()
    lifted[20:36, 20:50] = False
    assert not lifted.any()                                 # no square of the table


def test_two_thin_parts_of_one_colour_the_table_divides_stay_divided() -> None:
    height = np.zeros((40, 90), np.float32)
    candidate = np.zeros(height.shape, bool)
    candidate[10:30, 5:85] = True      # two plates 3 mm high, touching across a gap of table
    height[10:30, 5:44] = height[10:30, 46:85] = 0.003
    candidate[5:35, 85:90] = True      # and a taller part against them: the blob is not thin
    height[5:35, 85:90] = 0.03
    lab = _lab(height.shape, (50.0, 30.0, 20.0))
    lifted = raised_thin_blobs(candidate, height, height < 0.0025,
                               SegmentationParams(thin_lift_colour_floors=1.0), lab=lab)
    assert not lifted.any()


def test_a_lifted_colour_region_is_one_part_beside_a_taller_one() -> None:
    from tlessbot_ros.core.localise.instances import instances_at_scale

    height = np.full((80, 160), np.nan, np.float32)
    plate = np.zeros(height.shape, bool)
    plate[20:60, 10:50] = plate[33:47, 50:70] = plate[20:60, 70:110] = True  # two lobes, a neck
    height[plate] = 0.003
    block = np.zeros(height.shape, bool)
    block[10:70, 110:150] = True                            # a block 30 mm high against it
    height[block] = 0.03
    rgb = np.zeros(height.shape + (3,), np.uint8)
    rgb[plate], rgb[block] = (200, 60, 120), (200, 60, 110)
    args = (plate | block, rgb, rgb, SegmentationParams())
    cut = instances_at_scale(*args, height_m=height)[0]     # the blob's cores cut the plate
    assert len(np.unique(cut[plate])) == 2 and np.unique(cut[block]).tolist() == [1]
    regions = np.where(plate, 1, 0).astype(np.int32)        # the plate's lifted colour region
    labels = instances_at_scale(*args, height_m=height, thin_regions=regions)[0]
    assert np.unique(labels[plate]).tolist() == [1]
    assert np.count_nonzero(labels[block] == 2) >= 0.99 * block.sum()
    two = regions.copy()                                    # two thin parts: two regions
    two[:, 60:] = np.where(plate[:, 60:], 2, 0)
    labels = instances_at_scale(*args, height_m=height, thin_regions=two)[0]
    assert len({int(labels[40, 30]), int(labels[40, 90]), int(labels[40, 130])}) == 3



def test_a_taller_part_s_thin_flange_stays_with_it() -> None:
    from tlessbot_ros.core.localise.instances import instances_at_scale

    height = np.full((80, 120), np.nan, np.float32)
    flange = np.zeros(height.shape, bool)
    flange[10:70, 10:30] = True                   # a bracket's flange 3 mm high, 60 px wide...
    height[flange] = 0.003
    upright = np.zeros(height.shape, bool)
    upright[10:70, 30:70] = True                  # ... along its upright, 25 mm high
    height[upright] = 0.025
    rgb = np.zeros(height.shape + (3,), np.uint8)
    rgb[flange | upright] = (60, 90, 200)
    regions = np.where(flange, 1, 0).astype(np.int32)
    labels = instances_at_scale(flange | upright, rgb, rgb, SegmentationParams(),
                                height_m=height, thin_regions=regions)[0]
    assert np.unique(labels[flange | upright]).tolist() == [1]


def test_a_low_band_between_two_parts_is_not_lifted() -> None:
    height = np.zeros((60, 120), np.float32)
    lab = _lab(height.shape, (70.0, 0.0, 0.0))              # a grey table
    candidate = np.zeros(height.shape, bool)
    for cols in (np.s_[5:45], np.s_[75:115]):               # two black blocks 30 mm high...
        candidate[10:50, cols] = True
        height[10:50, cols] = 0.03
        lab[10:50, cols] = (20.0, 0.0, 0.0)
    candidate[20:40, 45:75] = True                          # ... a low band of one colour
    height[20:40, 45:75] = 0.003                            # between them (a pile's gap, a
    height[20:40:2, 45:75:2] = 0.001                        # part's foot), a quarter table
    lab[20:40, 45:75] = (45.0, 10.0, -45.0)
    table = height < 0.0025
    params = SegmentationParams(thin_lift_colour_floors=1.0)
    assert not raised_thin_blobs(candidate, height, table, params, lab=lab).any()
    bridged = raised_thin_blobs(candidate, height, table,
                                replace(params, thin_region_no_bridge=False), lab=lab)
    assert bridged[21:39, 46:74].all()
    one = candidate.copy()                                  # beside one block only: lifted
    one[10:50, 75:115] = False
    lifted = raised_thin_blobs(one, height, table, params, lab=lab)
    assert lifted[21:39, 46:74].all()


def test_the_lifted_regions_divide_the_side_view_only(monkeypatch) -> None:
    from tlessbot_ros.core.localise import segmentation

    rgb, depth, _, cam = _strip_scene()
    seen: dict[bool, object] = {}
    separate = segmentation.instances_at_scale

    def spy(*args, **kwargs):
        seen[kwargs['surfaces'] is not None] = kwargs['thin_regions']
        return separate(*args, **kwargs)

    monkeypatch.setattr(segmentation, 'instances_at_scale', spy)
    params = SegmentationParams(thin_lift_colour_floors=1.0)
    for side in (True, False):
        segment(rgb, depth_m=depth, intrinsics=cam.intrinsics,
                T_world_camera=cam.T_world_camera, split_by_depth=side, params=params)
    assert seen[True] is not None       # the side view: split by depth, its regions apart
    assert seen[False] is None          # the top view, farther: a thin part reads small
