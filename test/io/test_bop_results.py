"""BOP results CSV round trip and malformed rows."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import make_transform, rotation_about_axis
from tlessbot_ros.errors import DatasetError
from tlessbot_ros.io.bop_results import BopEstimate, read_results, write_results


def test_round_trip_keeps_metres_in_memory_and_mm_on_disk(tmp_path):
    T = make_transform(rotation_about_axis(np.array([1.0, 2, 3]), 0.7), [0.1, -0.02, 0.55])
    path = tmp_path / 'r.csv'
    write_results(path, [BopEstimate(1, 2, 5, 0.9, T, 0.25), BopEstimate(1, 3, 11, 0.5, T)])
    text = path.read_text().splitlines()
    assert text[0] == 'scene_id,im_id,obj_id,score,R,t,time'
    assert '100.000000 -20.000000 550.000000' in text[1]
    back = read_results(path)
    assert [(r.scene_id, r.im_id, r.obj_id) for r in back] == [(1, 2, 5), (1, 3, 11)]
    assert np.allclose(back[0].T_camera_object, T, atol=1e-8)
    assert back[0].time_s == 0.25 and back[1].time_s == -1


def test_header_is_optional(tmp_path):
    path = tmp_path / 'r.csv'
    path.write_text('0,1,2,1.0,1 0 0 0 1 0 0 0 1,0 0 500,-1\n')
    (r,) = read_results(path)
    assert r.T_camera_object[2, 3] == pytest.approx(0.5)


@pytest.mark.parametrize('line, message', [
    ('0,1,2,1.0,1 0 0 0 1 0 0 0 1,0 0 500', 'expected 7 fields'),
    ('0,x,2,1.0,1 0 0 0 1 0 0 0 1,0 0 500,-1', 'integers'),
    ('0,1,2,1.0,1 0 0 0 1 0 0 0,0 0 500,-1', 'R must be 9'),
    ('0,1,2,1.0,2 0 0 0 1 0 0 0 1,0 0 500,-1', 'not a rotation'),
    ('0,1,2,1.0,1 0 0 0 1 0 0 0 1,0 0 five,-1', 't must be 3'),
])
def test_malformed_rows_name_the_line(tmp_path, line, message):
    path = tmp_path / 'r.csv'
    path.write_text('scene_id,im_id,obj_id,score,R,t,time\n' + line + '\n')
    with pytest.raises(DatasetError, match=message) as info:
        read_results(path)
    assert 'r.csv:2' in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(DatasetError, match='cannot read'):
        read_results(tmp_path / 'nope.csv')
