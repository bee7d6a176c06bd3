"""A rig of one camera (rig.cameras: [side], [top] or any name): the localiser segments the one
view (nothing to fuse), the classifier and the pose stage read every part in that camera."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import CameraMount, Rig, check_camera_roles, default_rig
from tlessbot_ros.core.localise import segment
from tlessbot_ros.core.metrics import is_correct_cm_deg, pose_error
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.errors import CalibrationError


@pytest.fixture(scope='module')
def frame(tless_models_dir):
    """A simulated frame of the default rig, three parts on the table."""
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    sim = Simulator(load_models(tless_models_dir, ids=[5, 11, 21]), rig=default_rig(),
                    params=SimParams(parts_min=3, parts_max=3), seed=11)
    return sim.frame(0)


def _view(frame, camera: str) -> ViewInput:
    view = frame.views[camera]
    return ViewInput(view.rgb, view.depth_mm.astype(np.float32) / 1000.0, view.intrinsics,
                     view.T_world_camera)


def _one_camera_rig(name: str, camera: str = 'side') -> Rig:
    mount = default_rig()[camera]
    return Rig(cameras={name: CameraMount(name, mount.intrinsics, mount.T_world_camera)})


def test_a_rig_of_one_camera_of_any_name_is_accepted():
    assert check_camera_roles(['side']) == ('side',)
    assert check_camera_roles(['front']) == ('front',)
    for names in (['top', 'front'], [], ['']):
        with pytest.raises(CalibrationError, match='or runs on one camera of any name'):
            check_camera_roles(names)


@pytest.mark.parametrize('name', ['side', 'front'])
def test_one_view_is_segmented_alone_and_keeps_its_name(frame, name):
    view = _view(frame, 'side')
    fusion = PerceptionPipeline(rig=_one_camera_rig(name)).localise({name: view})
    assert set(fusion.labels) == {name} and fusion.method == 'single_view'
    alone = segment(view.rgb, depth_m=view.depth_m, intrinsics=view.intrinsics,
                    T_world_camera=view.T_world_camera, split_by_depth=True)
    np.testing.assert_array_equal(fusion.labels[name], alone.labels)
    assert fusion.labels[name].dtype == np.uint16 and fusion.labels[name].max() >= 3
    assert [i.instance_id for i in fusion.instances] == list(range(1, alone.count + 1))
    assert all(i.in_side and not i.in_top for i in fusion.instances)


def test_a_top_camera_alone_is_not_split_by_its_depth(frame):
    view = _view(frame, 'top')
    fusion = PerceptionPipeline(rig=_one_camera_rig('top', 'top')).localise({'top': view})
    alone = segment(view.rgb, depth_m=view.depth_m, intrinsics=view.intrinsics,
                    T_world_camera=view.T_world_camera, split_by_depth=False)
    np.testing.assert_array_equal(fusion.labels['top'], alone.labels)
    assert all(i.in_top and not i.in_side for i in fusion.instances)


def test_two_views_still_need_both_roles(frame):
    views = {'side': _view(frame, 'side'), 'front': _view(frame, 'top')}
    with pytest.raises(ValueError, match=r"top and side or one view; missing \['top'\]"):
        PerceptionPipeline(rig=default_rig()).localise(views)


def test_every_stage_runs_on_one_view_and_poses_its_parts(frame):
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.core.recognise import load_classifier
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES

    pipeline = PerceptionPipeline(rig=_one_camera_rig('front'),
                                  classifier=load_classifier(DEFAULT_CLASSIFIER),
                                  templates=TemplateDatabase.load(DEFAULT_TEMPLATES))
    result = pipeline.process({'front': _view(frame, 'side')})
    assert result.detections and all(d.view == 'front' for d in result.detections)
    truth = {gt.obj_id: gt.T_camera_object for gt in frame.views['side'].gt}
    correct = [d for d in result.detections if d.pose is not None and d.obj_id in truth and
               is_correct_cm_deg(pose_error(d.pose.T_camera_object, truth[d.obj_id]))]
    assert len(correct) >= 2, [(d.obj_id, d.pose) for d in result.detections]
