"""The pose stage's verification on real RealSense depth (../shared/data/sygrid_real_d435i,
frames 0 and 1, 29 parts; skipped without the shared data): given the right class first and
the four other parts after it, it keeps the right class. Measured: 18 of the 23 parts that keep
a pose (the others are judged unknown); 7 of 16 before the classes were compared at one
tolerance and ground-truth boxes stopped being taken for fragments (docs/bench/real-pose.md)."""
from __future__ import annotations

from tlessbot_ros.core.common import SIDE
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, oracle_labels


def test_verification_keeps_the_right_class_on_real_depth(shared_data, tmp_path):
    dataset = shared_data / 'sygrid_real_d435i'
    templates = tmp_path / 'templates.npz'
    assert main(['templates', '--models', str(dataset / 'models'), '--out',
                 str(templates)]) == 0
    database = TemplateDatabase.load(templates)
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
