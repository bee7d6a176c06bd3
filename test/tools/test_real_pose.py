"""The pose stage's verification on real RealSense depth (../shared/data/sygrid_real_d435i,
frames 0 and 1, 29 parts; skipped without the shared data): given the right class first and
the four other parts after it, it keeps the right class. Measured: 18 of the 23 parts that keep
a pose (the others are judged unknown); 7 of 16 before the classes were compared at one
tolerance and ground-truth boxes stopped being taken for fragments (docs/bench/real-pose.md).
With ``table_clearance_noise`` the long screws (10 mm across, their shafts lower still in the
D435i's smoothed depth) keep their shafts above a clearance that follows the noise measured on
the table: 2 of the 4 screws with depth fitted within 0.1 d of the truth, none with the fixed
4 mm (docs/bench/real-pose-gap.md)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tlessbot_ros.core.common import SIDE
from tlessbot_ros.core.metrics import adds
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, oracle_labels
from tlessbot_ros.tools.support.eval_scoring import load_scoring_models

SCREW = 4   # obj_000004, the long socket-head screw (71 x 10 mm)


@pytest.fixture(scope='module')
def real_templates(shared_data, tmp_path_factory):
    dataset = shared_data / 'sygrid_real_d435i'
    templates = tmp_path_factory.mktemp('real') / 'templates.npz'
    assert main(['templates', '--models', str(dataset / 'models'), '--out',
                 str(templates)]) == 0
    return dataset, TemplateDatabase.load(templates)


def test_verification_keeps_the_right_class_on_real_depth(real_templates):
    dataset, database = real_templates
    pipeline, kept, fitted = None, 0, 0
    for image in read_split(dataset, 'test', limit=2):
        if pipeline is None:
            pipeline = _first_pipeline({SIDE: image}, classifier=None, templates=database)
        classes = {k + 1: (gt.obj_id, *[o for o in sorted(database.objects) if o != gt.obj_id])
                   for k, gt in enumerate(image.gt)}
        view = ViewInput(image.rgb, image.depth_m, image.intrinsics, None)
        for detection in pipeline.estimate_poses({SIDE: view}, oracle_labels({SIDE: image}),
                                                 classes, box_mode=True):
            if detection.pose is not None:
                fitted += 1
                kept += detection.obj_id == image.gt[detection.instance_id - 1].obj_id
    assert fitted >= 20, f'{fitted} of 29 parts fitted'
    assert kept >= 0.7 * fitted, f'the right class kept on {kept} of {fitted}'


def test_thin_parts_keep_their_shape_above_the_real_table(real_templates):
    dataset, database = real_templates
    model = load_scoring_models(dataset / 'models', {SCREW})[SCREW]
    pipeline, errors = None, []
    for image in read_split(dataset, 'test', limit=2):
        if pipeline is None:
            pipeline = _first_pipeline({SIDE: image}, classifier=None, templates=database)
            pipeline.fit_params = replace(pipeline.fit_params,
                                          table_clearance_noise=True)
        view = ViewInput(image.rgb, image.depth_m, image.intrinsics, None)
        classes = {k + 1: gt.obj_id for k, gt in enumerate(image.gt)}
        for detection in pipeline.estimate_poses({SIDE: view}, oracle_labels({SIDE: image}),
                                                 classes, box_mode=True):
            gt = image.gt[detection.instance_id - 1]
            if gt.obj_id == SCREW:
                errors.append(np.inf if detection.pose is None else adds(
                    detection.pose.T_camera_object, gt.T_camera_object, model.vertices)
                    / model.diameter_m)
    assert len(errors) == 4
    assert sum(e < 0.1 for e in errors) >= 2, f'ADD-S / d of the screws: {errors}'
