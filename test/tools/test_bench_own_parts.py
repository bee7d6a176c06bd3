"""tlessbot bench own-parts: its per-set loss tables name the parts as evaluate's report does."""
from __future__ import annotations

from tlessbot_ros.tools.commands.bench.own_parts import _losses
from tlessbot_ros.tools.support.eval_breakdown import FP_CAUSES, MISS_CAUSES


def test_losses_name_the_parts_as_the_report_does():
    per_part = {'1': {'objects_gt': 3, 'iou07_rate': 1.0, 'top1': 0.5, 'recall_5cm5deg': 0.5},
                '2': {'objects_gt': 2, 'iou07_rate': 0.5, 'top1': 1.0, 'recall_5cm5deg': 1.0}}
    breakdown = {'missed': dict.fromkeys(MISS_CAUSES, 0),
                 'missed_by_obj': {'2': {**dict.fromkeys(MISS_CAUSES, 0), 'merged': 1}},
                 'false_pos': dict.fromkeys(FP_CAUSES, 0),
                 'false_pos_posed': dict.fromkeys(FP_CAUSES, 0),
                 'confusions': {'1 -> 2': 1, '2 -> 0': 1}}
    row = {'name': 'mine', 'per_part': per_part, 'breakdown': breakdown,
           'names': {'1': 'bracket_l', '2': 'plate'}}   # report.json's names
    text = '\n'.join(_losses(row))
    assert '| bracket_l | 3 | 1.00 | 0.50 | 0.50 | 0, 0, 0, 0 |' in text
    assert '| plate | 2 | 0.50 | 1.00 | 1.00 | 0, 1, 0, 0 |' in text
    assert 'Named as another part: bracket_l -> plate (1), plate -> 0 (1).' in text
