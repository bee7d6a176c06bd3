"""Part names: id <-> name, and names that cannot name a ROS topic."""
import pytest

from tlessbot_ros.conversions.topics import pose_topic
from tlessbot_ros.core.common import (
    check_part_name,
    check_part_names,
    part_id,
    part_name,
    suggest_part_name,
)
from tlessbot_ros.errors import PartNameError


def test_tless_parts_keep_obj_nn():
    assert part_name(5) == 'obj_05'
    assert part_name(23, {1: 'bracket'}) == 'obj_23'
    assert part_id('obj_05') == 5
    assert pose_topic(5) == '/objects/obj_05/pose'


def test_named_parts_round_trip():
    names = {1: 'bracket_l', 2: 'plate_40x60'}
    for obj_id, name in names.items():
        assert part_name(obj_id, names) == name
        assert part_id(name, names) == obj_id
    assert pose_topic(2, names) == '/objects/plate_40x60/pose'
    assert pose_topic('bracket_l') == '/objects/bracket_l/pose'
    with pytest.raises(PartNameError, match='no part named'):
        part_id('obj_01', names)


@pytest.mark.parametrize('stem, suggestion', [
    ('M6 bolt-2', 'M6_bolt_2'), ('6mm_plate', 'part_6mm_plate'), ('a__b', 'a_b'),
    ('tube.', 'tube')])
def test_invalid_names_say_how_to_rename(stem, suggestion):
    with pytest.raises(PartNameError, match=f'rename the file to {suggestion}.stl'):
        check_part_name(stem, source=f'{stem}.stl')
    assert suggest_part_name(stem) == suggestion
    assert check_part_name(suggestion) == suggestion


def test_repeated_names_refused():
    with pytest.raises(PartNameError, match='both named'):
        check_part_names({1: 'a', 2: 'a'})
