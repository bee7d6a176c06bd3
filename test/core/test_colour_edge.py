"""A piece of a patterned table's square that a depth bump lets through the table veto is
dropped; a thin part as high as the bump, found by its colour, is kept, and so are the pieces
of a thin part whose top the depth reads as table around them
(:mod:`~tlessbot_ros.core.localise.colour_edge`)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.localise import SegmentationParams, segment

BUMP_M = 0.0035   # between the depth cue's table (2.5 mm) and its candidates (4 mm)
SQUARE = (slice(50, 135), slice(20, 125))    # a pink checker square of the table, 105 px long
BUMP = (slice(80, 100), slice(60, 85))       # a smoothed-noise patch on it
STRIP = (slice(110, 124), slice(200, 270))   # a blue strip on the grey table, 70 px long
LOW_STRIP = (slice(170, 184), slice(160, 230))   # a green one the depth reads as table ...
RAISED = (slice(172, 182), slice(180, 205))      # ... but for a patch as high as the bump
# the parts' largest extent (m), smallest whole blob and longest look (px) in this view
PARTS = ((0.06, 60.0, 80.0),)
SHORT_PARTS = ((0.04, 60.0, 50.0),)   # shorter than the green strip


def _depth_of(raised: tuple, cam) -> np.ndarray:
    """(240, 320) float32 depth (m) of the table seen by ``cam``, the ``raised`` regions
    ``BUMP_M`` above it."""
    rays = np.linalg.inv(cam.intrinsics.K) @ np.vstack([
        np.mgrid[0:240, 0:320][::-1].reshape(2, -1), np.ones((1, 240 * 320))])
    R, t = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    along = (R[2] @ rays).reshape(240, 320)   # world height change per metre of depth
    height = np.zeros((240, 320))
    for region in raised:
        height[region] = BUMP_M
    return ((height - t[2]) / along).astype(np.float32)


def _centres(rgb: np.ndarray, depth: np.ndarray, cam, params: SegmentationParams
             ) -> list[tuple[int, int]]:
    """(row, column) centres of the instances ``segment`` finds."""
    seg = segment(rgb, depth_m=depth, intrinsics=cam.intrinsics,
                  T_world_camera=cam.T_world_camera, split_by_depth=False, params=params)
    return [tuple(int(v) for v in np.argwhere(seg.labels == i).mean(axis=0))
            for i in range(1, seg.count + 1)]


def _top_view() -> tuple[np.ndarray, np.ndarray, object]:
    """(rgb, depth_m, camera) of a grey table with a pink square, a raised patch on the
    square, a blue strip as high as the patch on the grey, and a green strip read as table
    but for a patch as high."""
    from tlessbot_ros.core.common import default_rig

    cam = default_rig(320, 240)['top']
    depth = _depth_of((BUMP, STRIP, RAISED), cam)
    rng = np.random.default_rng(0)
    rgb = np.empty((240, 320, 3))
    rgb[:] = (200, 200, 195)
    rgb[SQUARE] = (235, 120, 175)
    rgb[STRIP] = (40, 70, 170)
    rgb[LOW_STRIP] = (40, 160, 80)
    rgb = np.clip(rgb + rng.normal(0, 2.0, rgb.shape), 0, 255).astype(np.uint8)
    return rgb, depth, cam


def _found(params: SegmentationParams) -> list[tuple[int, int]]:
    return _centres(*_top_view(), params)


def _inside(centre: tuple[int, int], region: tuple[slice, slice]) -> bool:
    return region[0].start <= centre[0] < region[0].stop and \
        region[1].start <= centre[1] < region[1].stop


def test_a_raised_piece_of_a_table_square_is_not_a_part():
    centres = _found(SegmentationParams(whole_parts=PARTS))
    assert not any(_inside(c, BUMP) for c in centres)
    assert sum(_inside(c, STRIP) for c in centres) == 1
    assert sum(_inside(c, LOW_STRIP) for c in centres) == 1


def test_the_piece_is_found_without_the_test_or_the_parts_sizes():
    # what the test above guards against: the bump is a blob when the rule is off
    for params in (SegmentationParams(whole_parts=PARTS, colour_edge_floors=0.0),
                   SegmentationParams()):
        centres = _found(params)
        assert any(_inside(c, BUMP) for c in centres)
        assert sum(_inside(c, STRIP) for c in centres) == 1
        assert sum(_inside(c, LOW_STRIP) for c in centres) == 1


def test_a_piece_of_a_thin_part_is_kept_as_the_part_ends_its_colour():
    # the raised patch of the green strip has the strip's colour (read as table) around it,
    # as a piece of a square has; the strip ends within a part's length, a square does not
    assert sum(_inside(c, LOW_STRIP) for c in _found(SegmentationParams(whole_parts=PARTS))) == 1
    centres = _found(SegmentationParams(whole_parts=SHORT_PARTS))
    assert not any(_inside(c, LOW_STRIP) for c in centres)
    assert sum(_inside(c, STRIP) for c in centres) == 1


# A table of dark tiles shorter than the parts (30 px, every 50 px): the colour's region does
# not run on beyond a part, so only the outline tells a raised piece of a tile from a part.
TILE_PX, TILE_PITCH = 30, 50
TILE_BUMP = (slice(58, 72), slice(107, 123))   # inside the tile at rows 50-80, columns 100-130


def _tiled_view() -> tuple[np.ndarray, np.ndarray, object]:
    """(rgb, depth_m, camera): a grey table with dark tiles, a raised patch inside one tile,
    the blue strip as high, and the green strip read as table but for a patch as high."""
    _, _, cam = _top_view()
    rows, cols = np.mgrid[0:240, 0:320]
    rgb = np.empty((240, 320, 3))
    rgb[:] = (200, 200, 195)
    rgb[((rows % TILE_PITCH) < TILE_PX) & ((cols % TILE_PITCH) < TILE_PX)] = (70, 70, 75)
    rgb[STRIP] = (40, 70, 170)
    rgb[LOW_STRIP] = (40, 160, 80)
    rgb += np.random.default_rng(1).normal(0, 2.0, rgb.shape)
    return np.clip(rgb, 0, 255).astype(np.uint8), _depth_of((TILE_BUMP, STRIP, RAISED), cam), cam


def _found_on_tiles(params: SegmentationParams) -> list[tuple[int, int]]:
    return _centres(*_tiled_view(), params)


def test_a_raised_piece_of_a_tile_shorter_than_the_parts_is_not_a_part():
    centres = _found_on_tiles(SegmentationParams(whole_parts=PARTS))
    assert not any(_inside(c, TILE_BUMP) for c in centres)
    # a part steps all along its outline; a piece of a part (the green strip's raised patch)
    # steps nowhere but its colour is not common around it
    assert sum(_inside(c, STRIP) for c in centres) == 1
    assert sum(_inside(c, LOW_STRIP) for c in centres) == 1


def test_the_piece_of_a_tile_is_found_without_the_outline_test():
    # what the test above guards against: the tiles are too short for the region test alone
    centres = _found_on_tiles(SegmentationParams(
        whole_parts=PARTS, colour_edge_outline_share=0.0, colour_edge_pattern_share=0.0))
    assert any(_inside(c, TILE_BUMP) for c in centres)
    assert sum(_inside(c, STRIP) for c in centres) == 1


# A patch raising a whole tile (and a little of the grey around it): the piece's outline is
# the tile's own edge, so its colour steps all along it as a part's does; but its only colour
# is one the table shows all around, where a part shows its own.
WHOLE_TILE = (slice(100, 130), slice(150, 180))
WHOLE_TILE_BUMP = (slice(97, 133), slice(147, 183))


def _whole_tile_raised() -> tuple[np.ndarray, np.ndarray, object]:
    rgb, _, cam = _tiled_view()
    return rgb, _depth_of((WHOLE_TILE_BUMP, STRIP, RAISED), cam), cam


def test_a_raised_whole_tile_is_not_a_part():
    centres = _centres(*_whole_tile_raised(), SegmentationParams(whole_parts=PARTS))
    assert not any(_inside(c, WHOLE_TILE) for c in centres)
    assert sum(_inside(c, STRIP) for c in centres) == 1
    assert sum(_inside(c, LOW_STRIP) for c in centres) == 1


def test_the_whole_tile_is_found_without_the_pattern_test():
    # what the test above guards against: its outline steps, so the outline test keeps it
    centres = _centres(*_whole_tile_raised(), SegmentationParams(
        whole_parts=PARTS, colour_edge_pattern_share=0.0))
    assert sum(_inside(c, WHOLE_TILE) for c in centres) == 1
    assert sum(_inside(c, STRIP) for c in centres) == 1


# A plate of the tiles' own colour lying on the tiled table, 3.5 mm high but for a raised band
# above the depth cue's candidate level: its colour is the pattern's, but the depth finds a
# part in places, which a noise patch between the two levels never reaches.
PLATE = (slice(185, 225), slice(240, 300))
PLATE_BAND = (slice(185, 195), slice(240, 300))
BAND_M = 0.006


def test_a_plate_of_the_tiles_colour_that_the_depth_finds_in_places_is_kept():
    rgb, _, cam = _tiled_view()
    rgb[PLATE] = np.clip(70 + np.random.default_rng(2).normal(0, 2.0, rgb[PLATE].shape), 0, 255)
    depth = _depth_of((STRIP, RAISED, PLATE), cam)
    band = _depth_of((PLATE_BAND,), cam)
    closer = _depth_of((), cam) - band   # how much nearer the band's 3.5 mm put it
    depth[PLATE_BAND] -= closer[PLATE_BAND] * (BAND_M / BUMP_M - 1)
    centres = _centres(rgb, depth, cam, SegmentationParams(whole_parts=PARTS))
    assert sum(_inside(c, PLATE) for c in centres) == 1
    assert sum(_inside(c, STRIP) for c in centres) == 1


# A checker whose squares' edges are blurred (a lens, a sensor): a raised piece along a dark
# square's edge holds the square's colour and the edge's blends of it with the table's, none
# of them one part's; a grey part lying across such an edge, of a colour between the two, has
# it inside its outline too, away from the squares' colours.
EDGE_PIECE = (slice(55, 75), slice(126, 132))   # the tile at columns 100-129 ends at 130
GREY_PART = (slice(150, 170), slice(170, 190))  # across the tile edge at column 180


def _blurred_tiles_with(params: SegmentationParams) -> np.ndarray:
    """What ``drop_blobs_without_colour_edge`` keeps of the edge piece and the grey part, both
    found by colour alone (no depth candidate) on the blurred dark tiles."""
    import cv2

    from tlessbot_ros.core.localise.colour_edge import drop_blobs_without_colour_edge

    rows, cols = np.mgrid[0:240, 0:320]
    rgb = np.empty((240, 320, 3))
    rgb[:] = (200, 200, 195)
    rgb[((rows % TILE_PITCH) < TILE_PX) & ((cols % TILE_PITCH) < TILE_PX)] = (70, 70, 75)
    rgb = cv2.GaussianBlur(rgb, (0, 0), 1.0)
    rgb[GREY_PART] = (135, 135, 135)
    rgb = np.clip(rgb + np.random.default_rng(1).normal(0, 2.0, rgb.shape), 0, 255)
    foreground = np.zeros((240, 320), bool)
    foreground[EDGE_PIECE] = foreground[GREY_PART] = True
    return drop_blobs_without_colour_edge(foreground, rgb.astype(np.uint8),
                                          np.zeros_like(foreground), ~foreground, params)


def test_a_piece_along_a_blurred_square_edge_is_not_a_part():
    kept = _blurred_tiles_with(SegmentationParams(whole_parts=PARTS))
    assert not kept[EDGE_PIECE].any()
    assert kept[GREY_PART].all()


def test_the_edge_piece_is_kept_without_the_blends():
    # what the test above guards against: a third of the piece is the edge's blends, so under
    # colour_edge_pattern_share of it has the squares' own colours
    kept = _blurred_tiles_with(SegmentationParams(whole_parts=PARTS, colour_edge_blend_px=0))
    assert kept[EDGE_PIECE].all()
    assert kept[GREY_PART].all()


def test_the_blend_reach_must_not_be_negative():
    with pytest.raises(ValueError, match='colour_edge_blend_px'):
        SegmentationParams(colour_edge_blend_px=-1)
