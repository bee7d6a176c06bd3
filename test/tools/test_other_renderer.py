"""The bench's second renderer (scripts/other_renderer_scenes.py, issue 41): its depth model
on a step, and one tiny MuJoCo scene written and read back by the dataset reader (skipped
without mujoco and an offscreen OpenGL)."""
from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPTS = Path(__file__).resolve().parents[2] / 'scripts'


def _script(name: str):
    """A module of scripts/ (the scene script imports the depth model beside it)."""
    if str(SCRIPTS) not in sys.path:
        sys.path.insert(0, str(SCRIPTS))
    return importlib.import_module(name)


K = np.array([[615.0, 0, 319.5], [0, 615.0, 239.5], [0, 0, 1]])


def _step_depth() -> np.ndarray:
    """A wall at 0.6 m with a box face at 0.5 m over columns 300-379, rows 200-279."""
    z = np.full((480, 640), 0.6, np.float32)
    z[200:280, 300:380] = 0.5
    return z


def test_the_second_imager_shadows_a_band_left_of_a_nearer_box():
    depth = _script('other_renderer_depth')
    out = depth.stereo_depth_mm(_step_depth(), np.zeros((480, 640), bool), K,
                                np.random.default_rng(0)) / 1000.0
    row = out[240]
    # f B (1/0.5 - 1/0.6) = 11.3 px of wall hidden from the imager 55 mm to the right,
    # less the 2 px the box's edge fattens into
    assert np.all(row[300 - 9:298] == 0)
    assert np.all(row[384:400] > 0) and np.all(row[260:285] > 0)   # no band right of it
    wall = out[50:150, 50:250]
    assert abs(np.median(wall) - 0.6) < 0.001 and wall.std() < 0.002
    assert len(np.unique(wall)) > 1   # noisy, not the clean plane


def test_shiny_pixels_lose_depth_and_others_keep_it():
    depth = _script('other_renderer_depth')
    shiny = np.zeros((480, 640), bool)
    shiny[220:260, 320:360] = True
    out = depth.stereo_depth_mm(_step_depth(), shiny, K, np.random.default_rng(1))
    assert np.mean(out[220:260, 320:360] == 0) > 0.5
    inner = (slice(203, 277), slice(303, 377))   # the box face but its edge pixels
    assert np.mean(out[inner][~shiny[inner]] == 0) < 0.02


def _box_obj(path: Path, size_mm: tuple[float, float, float]) -> None:
    x, y, z = size_mm
    corners = [(a, b, c) for a in (0, x) for b in (0, y) for c in (0, z)]
    faces = [(1, 3, 4), (1, 4, 2), (5, 6, 8), (5, 8, 7), (1, 2, 6), (1, 6, 5),
             (3, 7, 8), (3, 8, 4), (1, 5, 7), (1, 7, 3), (2, 4, 8), (2, 8, 6)]
    path.write_text(''.join(f'v {a} {b} {c}\n' for a, b, c in corners)
                    + ''.join(f'f {a} {b} {c}\n' for a, b, c in faces))


def _tiny_scenes(folder: Path, *more: str) -> Path:
    """One frame of two boxes at 320 x 240 (skips without mujoco or offscreen OpenGL)."""
    os.environ.setdefault('MUJOCO_GL', 'egl')
    mujoco = pytest.importorskip('mujoco')
    try:
        mujoco.Renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8).close()
    except Exception as error:   # no offscreen OpenGL here
        pytest.skip(f'MuJoCo cannot render offscreen: {error}')
    models = folder / 'models'
    models.mkdir()
    _box_obj(models / 'obj_01.obj', (40, 30, 20))
    _box_obj(models / 'obj_02.obj', (50, 50, 6))
    out = folder / 'scenes'
    _script('other_renderer_scenes').main([
        '--models', str(models), '--out', str(out), '--frames', '1', '--parts-min', '2',
        '--parts-max', '2', '--width', '320', '--height', '240', *more])
    return out


def test_a_tiny_mujoco_scene_reads_back_with_its_truth(tmp_path):
    from tlessbot_ros.io.bop import read_split

    out = _tiny_scenes(tmp_path)
    views = {s: list(read_split(out, s)) for s in ('test_top', 'test_side')}
    assert [len(v) for v in views.values()] == [1, 1]
    for [image] in views.values():
        assert sorted(gt.obj_id for gt in image.gt) == [1, 2]
        for gt in image.gt:
            size = np.array([40, 30, 20] if gt.obj_id == 1 else [50, 50, 6]) / 1000.0
            corners = np.array([[a, b, c] for a in (0, size[0]) for b in (0, size[1])
                                for c in (0, size[2])])
            world = image.T_world_camera @ gt.T_camera_object
            lowest = (corners @ world[:3, :3].T + world[:3, 3])[:, 2].min()
            assert -0.001 < lowest < 0.03    # on the table or on the other part
            camera = corners @ gt.T_camera_object[:3, :3].T + gt.T_camera_object[:3, 3]
            uv = camera @ image.intrinsics.K.T
            uv = uv[:, :2] / uv[:, 2:]
            ys, xs = np.nonzero(gt.mask)
            assert gt.visib_fract > 0.3 and len(xs) == gt.px_count_visib
            assert xs.min() >= uv[:, 0].min() - 1.5 and xs.max() <= uv[:, 0].max() + 1.5
            assert ys.min() >= uv[:, 1].min() - 1.5 and ys.max() <= uv[:, 1].max() + 1.5
            seen = image.depth_m[gt.mask]
            near, far = camera[:, 2].min(), camera[:, 2].max()
            assert np.nanmedian(seen) == pytest.approx((near + far) / 2, abs=far - near + 0.005)


def test_the_depth_model_applied_to_clean_scenes_keeps_the_table(tmp_path):
    from tlessbot_ros.io.bop import read_split

    clean = _tiny_scenes(tmp_path, '--depth', 'clean')
    depth = _script('other_renderer_depth')
    depth.redepth(clean, tmp_path / 'stereo', depth.StereoDepthParams())
    [before] = read_split(clean, 'test_side')
    [after] = read_split(tmp_path / 'stereo', 'test_side')
    table = np.isfinite(after.depth_m) & ~np.any([gt.mask for gt in before.gt], axis=0)
    error = after.depth_m[table] - before.depth_m[table]
    assert table.mean() > 0.8 and abs(np.median(error)) < 0.001
    assert 0 < np.abs(error).mean() < 0.003   # noisy, within a few mm at 0.6 m
