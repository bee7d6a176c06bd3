"""The message packages built from interfaces/ (scripts/interfaces.sh) carry the type hashes of
ROS 2 Jazzy's own, so tf2, RViz and a Jazzy arm read what the graph publishes.

Two independent references: rosbags' stored Jazzy type store (tf2_msgs), and the hashes that
Jazzy's rosidl generated for vision_msgs 4.1 (``detection3_d_array__description.c`` of a Jazzy
build: the top-level hash and its referenced types' expected hashes), which rosbags also derives
from our .msg text. Our generated packages' own hashes come from their installed type
descriptions (``share/<pkg>/msg/<Type>.json``) and from rclpy at run time.
"""
import json
import sys
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

REPO = Path(__file__).resolve().parents[2]
PREFIX = Path(sys.prefix)

# vision_msgs 4.1 in Jazzy (see the module docstring).
JAZZY_VISION_MSGS = {
    'ObjectHypothesis': '51da43cec11c01957a64d1e05a24acd18aae7745ec30b74348ad5f6d634f7f90',
    'ObjectHypothesisWithPose': '41c12344c0396c48b81df12467c192d99b2a0eb1463c5c37194e4223251c80bc',
    'BoundingBox3D': 'bbb73a65c163d7f9bb29009c7bde9f7faa576bd2d23299c4511d19230dab4698',
    'Detection3D': 'ddd703be132ab0b69d33121f1bb034132bfbb3b0ac5f9fb1516005ba1c8a265b',
    'Detection3DArray': '793f5eab9595ac1c0da07873cc859db42eae51f0ee76056db8562515d830e018',
}


def installed_hash(package: str, name: str) -> str:
    path = PREFIX / 'share' / package / 'msg' / f'{name}.json'
    assert path.exists(), f'{path} missing: run make setup (scripts/interfaces.sh)'
    hashes = json.loads(path.read_text())['type_hashes']
    return next(h['hash_string'] for h in hashes if h['type_name'] == f'{package}/msg/{name}')


def test_tf2_msgs_hash_equals_rosbags_jazzy_store():
    store = get_typestore(Stores.ROS2_JAZZY)
    assert installed_hash('tf2_msgs', 'TFMessage') == store.hash_rihs01('tf2_msgs/msg/TFMessage')


@pytest.mark.parametrize('name', sorted(JAZZY_VISION_MSGS))
def test_vision_msgs_hashes_equal_jazzy(name):
    assert installed_hash('vision_msgs', name) == f'RIHS01_{JAZZY_VISION_MSGS[name]}'


def test_vision_msgs_sources_hash_as_jazzy_in_rosbags():
    """rosbags hashes our .msg text (on its Jazzy std/geometry types) to the same values."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted((REPO / 'interfaces' / 'vision_msgs' / 'msg').glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'vision_msgs/msg/{path.stem}'))
    store.register(types)
    for name, digest in JAZZY_VISION_MSGS.items():
        assert store.hash_rihs01(f'vision_msgs/msg/{name}') == f'RIHS01_{digest}'


def test_a_wrong_definition_changes_the_hash():
    """The comparison can fail: one renamed field gives another hash."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg('string class_name\nfloat64 score\n',
                                      'vision_msgs/msg/ObjectHypothesis'))
    assert store.hash_rihs01('vision_msgs/msg/ObjectHypothesis') != \
        f'RIHS01_{JAZZY_VISION_MSGS["ObjectHypothesis"]}'
