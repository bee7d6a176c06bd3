"""tlessbot objects: the pure formatters of an answer."""
import json

import numpy as np

from tlessbot_ros.tools.commands.objects import answer_record, format_answer
from tlessbot_ros.tools.support.arm_client import Answer, PartAnswer


def answer(success=True):
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.02, 0.03]
    part = PartAnswer('obj_05', 'obj_05_2', 0.91, 'world', T, (0.08, 0.05, 0.04), T.copy())
    return Answer(success, '' if success else 'no frame completed within 1.0 s', 2_500_000_000,
                  [part] if success else [], 0.123)


def test_text_lists_every_part():
    text = format_answer(answer())
    assert '1 parts at stamp 2.500 s (answered in 123 ms)' in text
    assert 'obj_05_2' in text and 'x=+0.1000 y=-0.0200 z=+0.0300' in text
    assert format_answer(answer(False)) == 'no answer: no frame completed within 1.0 s'


def test_json_record_round_trips():
    record = json.loads(json.dumps(answer_record(answer())))
    part = record['parts'][0]
    assert record['success'] and record['stamp_ns'] == 2_500_000_000
    assert part['instance'] == 'obj_05_2' and part['T_world_part_tf'][0][3] == 0.1
