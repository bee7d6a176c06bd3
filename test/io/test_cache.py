"""Start-up cache of the pose stage's derived arrays (io/cache.py, core/pose/derived.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import PoseEstimator, TemplateDatabase
from tlessbot_ros.io.cache import (
    cache_dir,
    derived_cache_path,
    load_derived,
    store_derived,
    warm_pose_stage,
)


@pytest.fixture(scope='module')
def templates_file(part21_seen_from_the_side, tmp_path_factory):
    db = part21_seen_from_the_side[0]
    path = tmp_path_factory.mktemp('templates') / 'templates.npz'
    db.save(path)
    return path


def test_the_cache_dir_follows_the_environment(tmp_path):
    assert cache_dir({'TLESSBOT_CACHE_DIR': str(tmp_path)}) == tmp_path
    assert cache_dir({'XDG_CACHE_HOME': '/x'}).as_posix() == '/x/tlessbot_ros'
    assert cache_dir({'HOME': '/h'}).as_posix() == '/h/.cache/tlessbot_ros'


def test_restored_arrays_equal_the_built_ones_and_give_the_same_pose(
        templates_file, part21_seen_from_the_side, tmp_path):
    built = TemplateDatabase.load(templates_file)
    assert store_derived(built, templates_file, directory=tmp_path) == \
        derived_cache_path(templates_file, directory=tmp_path)
    restored = TemplateDatabase.load(templates_file)
    assert load_derived(restored, templates_file, directory=tmp_path)
    for obj_id in built.objects:
        a, b = built[obj_id], restored[obj_id]
        assert a.nearest_grid().origin.tolist() == b.nearest_grid().origin.tolist()
        np.testing.assert_array_equal(a.nearest_grid().index, b.nearest_grid().index)
        np.testing.assert_array_equal(a.nearest_grid().distance, b.nearest_grid().distance)
        for ta, tb in zip(a.templates, b.templates):
            np.testing.assert_array_equal(ta.fpfh, tb.fpfh)
            np.testing.assert_array_equal(ta.normals, tb.normals)
    _, depth, mask, _ = part21_seen_from_the_side
    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.core.pose import roi_cloud

    side = default_rig()['side']
    points = roi_cloud(depth, mask, side.intrinsics)
    poses = [PoseEstimator(db).estimate(points, 21, T_world_camera=side.T_world_camera).best
             for db in (built, restored)]
    np.testing.assert_array_equal(poses[0].T_camera_object, poses[1].T_camera_object)


def test_the_near_turns_listed_at_warm_up_are_kept(templates_file, tmp_path):
    from tlessbot_ros.core.pose import near_turns
    built = TemplateDatabase.load(templates_file)
    listed = near_turns(built[21])                  # built now, kept with the derived arrays
    store_derived(built, templates_file, directory=tmp_path)
    restored = TemplateDatabase.load(templates_file)
    assert load_derived(restored, templates_file, directory=tmp_path)
    kept = {k: v for k, v in restored[21].derived_items().items() if k[0] == 'near_turns'}
    assert len(kept) == 1
    np.testing.assert_array_equal(next(iter(kept.values())), listed)
    assert near_turns(restored[21]) is next(iter(kept.values()))   # read, not built again


def test_a_foreign_or_broken_cache_is_ignored(templates_file, tmp_path):
    db = TemplateDatabase.load(templates_file)
    path = store_derived(db, templates_file, directory=tmp_path)
    other = tmp_path / 'other.npz'
    other.write_bytes(templates_file.read_bytes() + b'\0')   # another file, another name
    assert not load_derived(TemplateDatabase.load(templates_file), other, directory=tmp_path)
    path.write_bytes(path.read_bytes()[:1000])               # truncated mid-write elsewhere
    fresh = TemplateDatabase.load(templates_file)
    assert not load_derived(fresh, templates_file, directory=tmp_path)
    assert all(t.fpfh is None for o in fresh.objects.values() for t in o.templates)


def test_a_second_warm_up_reads_the_cache(templates_file, tmp_path):
    first = warm_pose_stage(PerceptionPipeline(templates=TemplateDatabase.load(templates_file)),
                            templates_file, directory=tmp_path)
    second = warm_pose_stage(PerceptionPipeline(templates=TemplateDatabase.load(
        templates_file)), templates_file, directory=tmp_path)
    assert not first.from_cache and first.stored is not None
    assert second.from_cache and second.stored is None


def test_an_unwritable_cache_only_costs_time(templates_file, tmp_path):
    blocked = tmp_path / 'file'
    blocked.write_text('not a folder')
    assert store_derived(TemplateDatabase.load(templates_file), templates_file,
                         directory=blocked / 'cache') is None
