"""The box in the pose search on real RealSense depth (../shared/data/sygrid_real_d435i, frames 0
and 1, 29 parts, piled; skipped without the shared data): a ground-truth box is its part's
visible extent, so in box mode the fit weighs each pose by the share of the box its projected
model covers (``FitParams.box_cover``). The long screws, whose shafts the fixed 4 mm table
clearance cuts off in the D435i's smoothed depth, are fitted along the box that still spans the
shaft: 2 of the 4 screws with depth within 0.1 d of the truth, none without the box; 15 of
the 29 parts, 13 without (docs/bench/box-search.md). The tests ask for one part less than
measured (a run on another host may move a part) and still fail without the box."""
from __future__ import annotations

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
def real_fits(shared_data, tmp_path_factory):
    """{(frame, box): (class, ADD-S / diameter to the truth, inf without a pose)} of the true
    classes fitted on the ground-truth boxes."""
    dataset = shared_data / 'sygrid_real_d435i'
    templates = tmp_path_factory.mktemp('real') / 'templates.npz'
    assert main(['templates', '--models', str(dataset / 'models'), '--out',
                 str(templates)]) == 0
    database = TemplateDatabase.load(templates)
    models = load_scoring_models(dataset / 'models', set(database.objects))
    pipeline, errors = None, {}
    for image in read_split(dataset, 'test', limit=2):
        if pipeline is None:
            pipeline = _first_pipeline({SIDE: image}, classifier=None, templates=database)
        view = ViewInput(image.rgb, image.depth_m, image.intrinsics, None)
        classes = {k + 1: gt.obj_id for k, gt in enumerate(image.gt)}
        for detection in pipeline.estimate_poses({SIDE: view}, oracle_labels({SIDE: image}),
                                                 classes, box_mode=True):
            gt = image.gt[detection.instance_id - 1]
            model = models[gt.obj_id]
            errors[image.im_id, detection.instance_id] = (gt.obj_id, np.inf) \
                if detection.pose is None else (gt.obj_id, adds(
                    detection.pose.T_camera_object, gt.T_camera_object, model.vertices)
                    / model.diameter_m)
    return errors


def test_the_box_keeps_the_screws_shafts_the_table_clearance_cuts_off(real_fits):
    screws = [e for obj_id, e in real_fits.values() if obj_id == SCREW]
    assert len(screws) == 4
    assert sum(e < 0.1 for e in screws) >= 1, f'ADD-S / d of the screws: {screws}'


def test_more_parts_are_fitted_within_a_tenth_of_their_size_with_the_box(real_fits):
    assert len(real_fits) == 29
    near = sum(e < 0.1 for _, e in real_fits.values())
    assert near >= 14, f'{near} of 29 parts within 0.1 d'
