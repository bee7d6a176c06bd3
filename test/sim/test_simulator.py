import numpy as np
import open3d as o3d
import pytest

from tlessbot_ros.core.common import (
    default_rig,
    depth_to_points,
    invert_transform,
    transform_points,
)
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim.noise import DepthNoiseParams
from tlessbot_ros.sim.simulator import SimParams, Simulator

IDS = [5, 11, 19, 25]


@pytest.fixture(scope='module')
def models(tless_models_dir):
    return load_models(tless_models_dir, ids=IDS)


@pytest.fixture(scope='module')
def sim(models):
    return Simulator(models, rig=default_rig(320, 240), params=SimParams(parts_min=3), seed=7)


@pytest.fixture(scope='module')
def frames(sim):
    return [sim.frame(i) for i in range(3)]


def _distance_scene(model):
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(model.vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(model.faces)
    scene.add_triangles(mesh)
    return scene


def test_frame_structure(frames, sim):
    for frame in frames:
        assert set(frame.views) == {'top', 'side'}
        assert 3 <= len(frame.objects) <= 8
        for view in frame.views.values():
            assert view.rgb.shape == (240, 320, 3) and view.rgb.dtype == np.uint8
            assert view.depth_mm.dtype == np.uint16 and view.depth_clean_m.dtype == np.float32
            assert view.instance.dtype == np.int32
            assert len(view.gt) == len(frame.objects)
            for gt, obj in zip(view.gt, frame.objects):
                assert gt.obj_id == obj.obj_id
                assert np.allclose(gt.T_camera_object,
                                   invert_transform(view.T_world_camera) @ obj.T_world_object)
                assert 0 <= gt.px_count_visib <= gt.px_count_all
                assert 0.0 <= gt.visib_fract <= 1.0
                if gt.px_count_visib:
                    x, y, w, h = gt.bbox_visib
                    rows, cols = np.nonzero(gt.mask_visib)
                    assert (x, y, x + w - 1, y + h - 1) == (cols.min(), rows.min(), cols.max(),
                                                            rows.max())
                    bx, by, bw, bh = gt.bbox_obj
                    assert bx <= x and by <= y and bx + bw >= x + w and by + bh >= y + h


def test_parts_rest_on_table_without_overlap(frames, models):
    for frame in frames:
        for obj in frame.objects:
            v = transform_points(obj.T_world_object, models[obj.obj_id].vertices)
            assert v[:, 2].min() == pytest.approx(0.0, abs=1e-6)
        # No interpenetration: a part's vertices are not inside another part (occupancy of the
        # other closed mesh, tolerance for touching).
        for a, obj_a in enumerate(frame.objects):
            for b, obj_b in enumerate(frame.objects):
                if a == b:
                    continue
                scene = _distance_scene(models[obj_b.obj_id])
                T_b_a = invert_transform(obj_b.T_world_object) @ obj_a.T_world_object
                pts = transform_points(T_b_a, models[obj_a.obj_id].vertices[::5])
                dist = scene.compute_signed_distance(o3d.core.Tensor(pts.astype(np.float32)))
                assert dist.numpy().min() > -0.002


def test_depth_agrees_with_mesh_at_gt_pose(frames, models):
    for frame in frames:
        for view in frame.views.values():
            for gt in view.gt:
                if gt.px_count_visib < 30:
                    continue
                scene = _distance_scene(models[gt.obj_id])
                T_oc = invert_transform(gt.T_camera_object)
                # Clean depth: on the surface up to float precision.
                pts, _ = depth_to_points(view.depth_clean_m, view.intrinsics.K,
                                         mask=gt.mask_visib)
                d = scene.compute_distance(o3d.core.Tensor(
                    transform_points(T_oc, pts).astype(np.float32))).numpy()
                assert d.max() < 2e-4
                # Noisy depth: within the noise of the surface (sigma ~1-2.5 mm here).
                noisy = view.depth_mm.astype(np.float32) / 1000.0
                valid = gt.mask_visib & (view.depth_mm > 0)
                if valid.sum() < 20:
                    continue
                pts, _ = depth_to_points(noisy, view.intrinsics.K, mask=valid)
                d = scene.compute_distance(o3d.core.Tensor(
                    transform_points(T_oc, pts).astype(np.float32))).numpy()
                assert np.median(d) < 0.002
                assert np.mean(d < 0.008) > 0.97


def test_masks_match_depth(frames):
    for frame in frames:
        for view in frame.views.values():
            for k, gt in enumerate(view.gt):
                assert np.array_equal(gt.mask_visib, view.instance == k)
            pts, pix = depth_to_points(view.depth_clean_m, view.intrinsics.K)
            z_world = transform_points(view.T_world_camera, pts)[:, 2]
            on_part = view.instance[pix[:, 0], pix[:, 1]] >= 0
            assert np.abs(z_world[~on_part]).max() < 1e-4  # background = the table plane
            assert np.all(z_world[on_part] > -1e-4)
            assert np.mean(z_world[on_part] > 0.002) > 0.9
            # Noisy depth is invalid or close to the clean depth.
            valid = view.depth_mm > 0
            err = np.abs(view.depth_mm[valid] / 1000.0 - view.depth_clean_m[valid])
            assert np.percentile(err, 99) < 0.01
            assert 0.7 < valid.mean() < 0.999


def test_same_seed_same_bytes(models, sim, frames):
    again = Simulator(models, rig=default_rig(320, 240), params=SimParams(parts_min=3), seed=7)
    frame = again.frame(1)
    for name, view in frame.views.items():
        ref = frames[1].views[name]
        assert view.rgb.tobytes() == ref.rgb.tobytes()
        assert view.depth_mm.tobytes() == ref.depth_mm.tobytes()
        assert view.instance.tobytes() == ref.instance.tobytes()
    other = Simulator(models, rig=default_rig(320, 240), params=SimParams(parts_min=3), seed=8)
    assert other.frame(1).views['top'].rgb.tobytes() != frames[1].views['top'].rgb.tobytes()


def test_empty_table_matches_background(sim, frames):
    empty = sim.empty_table(0)
    for name, view in frames[0].views.items():
        bg = empty[name]
        assert np.all(bg.instance == -1) and bg.gt == []
        far = view.instance == -1
        diff = np.abs(bg.rgb.astype(int) - view.rgb.astype(int)).max(axis=2)[far]
        assert np.median(diff) <= 6  # same table and light; only noise and shadows differ
        assert np.mean(diff > 40) < 0.1


def test_visib_fract_of_occluded_parts(models):
    # A crowded scene: occlusions happen, and visib_fract < 1 exactly when something covers.
    sim = Simulator(models, rig=default_rig(320, 240),
                    params=SimParams(parts_min=4, parts_max=4, cluster_prob=1.0,
                                     area_radius_m=0.08), seed=3)
    seen = []
    for i in range(3):
        for view in sim.frame(i).views.values():
            seen += [g.visib_fract for g in view.gt]
    assert min(seen) < 0.95
    assert max(seen) == pytest.approx(1.0)


def test_noise_scale_zero_gives_clean_depth(models):
    sim = Simulator(models, rig=default_rig(320, 240),
                    params=SimParams(parts_max=2, noise_scale=0.0,
                                     noise=DepthNoiseParams(projector_shadow=False)), seed=1)
    view = sim.frame(0).views['side']
    expected = np.rint(view.depth_clean_m * 1000.0).astype(np.uint16)
    assert np.array_equal(view.depth_mm, expected)


def test_params_validation():
    with pytest.raises(ValueError, match='materials'):
        SimParams(materials=('gold',))
    with pytest.raises(ValueError, match='tables'):
        SimParams(tables=('marble',))
    with pytest.raises(ValueError, match='parts_min'):
        SimParams(parts_min=3, parts_max=2)


def test_px_count_all_matches_rendering_the_part_alone(frames, models):
    from tlessbot_ros.core.common import MeshRenderer

    frame = min(frames, key=lambda f: min(g.visib_fract for g in f.views['side'].gt))
    for view in frame.views.values():
        for obj, gt in zip(frame.objects, view.gt):
            renderer = MeshRenderer()
            model = models[obj.obj_id]
            renderer.add_mesh(model.vertices, model.faces, obj.T_world_object)
            alone = renderer.render(view.intrinsics, view.T_world_camera).instance == 0
            assert abs(int(alone.sum()) - gt.px_count_all) <= max(2, 0.002 * gt.px_count_all)
            assert np.all(alone[gt.mask_visib])  # visible pixels are part of the full mask
