"""The simulator's ChArUco board: it changes only the table's colour where it lies, and its
frames give the simulated rig back through the board calibration."""
import numpy as np
import pytest

from tlessbot_ros.core.calibrate import BoardSpec, calibrate_rig
from tlessbot_ros.core.common import (
    CameraMount,
    Rig,
    d415_intrinsics,
    default_rig,
    invert_transform,
    look_at,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim import shading
from tlessbot_ros.sim.board import SimBoard
from tlessbot_ros.sim.simulator import SimParams, Simulator

IDS = [5, 11, 19, 25]


@pytest.fixture(scope='module')
def models(tless_models_dir):
    return load_models(tless_models_dir, ids=IDS)


def moved_rig() -> Rig:
    """config/cell.yaml's cameras moved by up to 5 cm and turned by up to 12 degrees."""
    intrinsics = d415_intrinsics()
    top = look_at([0.03, -0.02, 1.12], [0.02, 0.01, 0.0], [0.0, 1.0, 0.0])
    top[:3, :3] = rotation_about_axis([1.0, 0.4, 0.0], np.radians(8.0)) @ top[:3, :3]
    side = look_at([0.04, -0.26, 0.57], [0.03, -0.02, 0.0], [0.0, 0.0, 1.0])
    side[:3, :3] = rotation_about_axis([0.2, 0.1, 1.0], np.radians(12.0)) @ side[:3, :3]
    return Rig(cameras={'top': CameraMount('top', intrinsics, top),
                        'side': CameraMount('side', intrinsics, side)})


def _board_pixels(view, board: SimBoard, pad_px: int = 4) -> np.ndarray:
    """(H, W) bool pixels whose table point lies on the print, grown by ``pad_px``."""
    import cv2

    depth, xy = shading.table_geometry(view.intrinsics, view.T_world_camera)
    T = invert_transform(board.T_world_board)
    local = xy @ T[:2, :2].T + T[:2, 3]
    half = np.array(board.spec.size_m) / 2 + board.margin_m
    on = (np.abs(local[..., 0]) <= half[0]) & (np.abs(local[..., 1]) <= half[1]) & (depth > 0)
    return cv2.dilate(on.astype(np.uint8), np.ones((2 * pad_px + 1,) * 2, np.uint8)) > 0


def test_the_board_changes_only_the_colour_where_it_lies(models):
    board = SimBoard(x_m=0.02, y_m=-0.03, yaw_deg=15.0)
    rig = default_rig(320, 240)
    plain = Simulator(models, rig=rig, params=SimParams(parts_max=3), seed=11)
    with_board = Simulator(models, rig=rig, params=SimParams(parts_max=3, board=board), seed=11)
    assert SimParams().board is None  # off by default
    for index in range(2):
        a, b = plain.frame(index), with_board.frame(index)
        assert [o.obj_id for o in a.objects] == [o.obj_id for o in b.objects]
        for name in ('top', 'side'):
            va, vb = a.views[name], b.views[name]
            # Flat on the table: depth, instances and ground truth are those without it.
            for attribute in ('depth_mm', 'depth_clean_m', 'instance'):
                assert np.array_equal(getattr(va, attribute), getattr(vb, attribute))
            for ga, gb in zip(va.gt, vb.gt):
                assert ga.px_count_visib == gb.px_count_visib
            # Colour: the same bytes off the print (same light, exposure and noise), the
            # print's black and white on it.
            on = _board_pixels(va, board)
            assert on.mean() > 0.05
            assert np.array_equal(va.rgb[~on], vb.rgb[~on])
            grey = vb.rgb[on & (vb.instance < 0)].mean(axis=1)
            assert np.percentile(grey, 95) - np.percentile(grey, 5) > 80


def test_the_simulated_board_gives_back_the_rig(models):
    # Frames of the board on an empty table, with cameras moved and turned from
    # config/cell.yaml: the board calibration finds them within 5 mm and 0.5 degrees.
    rig = moved_rig()
    board = SimBoard(spec=BoardSpec(), x_m=0.01, y_m=0.02, yaw_deg=-10.0)
    sim = Simulator(models, rig=rig, params=SimParams(parts_min=0, parts_max=0, board=board),
                    seed=5)
    frames = [sim.frame(i) for i in range(3)]
    assert all(not frame.objects for frame in frames)
    images = {name: [(f.views[name].rgb, f.views[name].intrinsics) for f in frames]
              for name in rig.cameras}
    measured, reports = calibrate_rig(images, board.spec, T_world_board=board.T_world_board)
    for name in ('top', 'side'):
        T, truth = measured[name].T_world_camera, rig[name].T_world_camera
        assert reports[name].used == 3
        assert 1000 * np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 5.0
        assert rotation_angle_deg(T, truth) < 0.5
    relative = measured.T_a_b('top', 'side')
    expected = rig.T_a_b('top', 'side')
    assert 1000 * np.linalg.norm(relative[:3, 3] - expected[:3, 3]) < 5.0
    assert rotation_angle_deg(relative, expected) < 0.5


def test_board_params_validation():
    with pytest.raises(ValueError, match='ink_albedo'):
        SimBoard(ink_albedo=0.9)
    with pytest.raises(ValueError, match='parts_min'):
        SimParams(parts_min=-1)
