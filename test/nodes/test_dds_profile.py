"""The package's Fast DDS profile is used unless the user chose one or another middleware."""
from __future__ import annotations

import xml.etree.ElementTree as ElementTree

import pytest

pytestmark = pytest.mark.ros


def test_profile_is_set_when_nothing_is_chosen():
    from tlessbot_ros.nodes.common import DDS_PROFILE_VARIABLES, use_package_dds_profile

    environ: dict[str, str] = {}
    path = use_package_dds_profile(environ)
    assert path is not None and path.endswith('fastdds.xml')
    assert all(environ[name] == path for name in DDS_PROFILE_VARIABLES)
    root = ElementTree.parse(path).getroot()
    sizes = [int(e.text) for e in root.iter() if e.tag.endswith('segment_size')]
    assert sizes and min(sizes) >= 4 * 2**20   # a whole two-view frame fits unfragmented


@pytest.mark.parametrize('environ', [
    {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/my_profile.xml'},
    {'FASTDDS_DEFAULT_PROFILES_FILE': '/etc/my_profile.xml'},
    {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'},
])
def test_a_users_choice_is_left_alone(environ):
    from tlessbot_ros.nodes.common import use_package_dds_profile

    before = dict(environ)
    assert use_package_dds_profile(environ) is None
    assert environ == before


def test_freed_buffers_are_kept_unless_the_user_tuned_malloc():
    from tlessbot_ros.nodes.common import keep_freed_buffers

    assert keep_freed_buffers(environ={'MALLOC_TRIM_THRESHOLD_': '0'}) is False
    # The test runs on glibc (Debian); elsewhere the call reports that it did nothing.
    assert keep_freed_buffers(environ={}) is True


def test_udp_profile_has_large_socket_buffers_and_no_shared_memory(tmp_path):
    from tlessbot_ros.io.config import package_path
    from tlessbot_ros.tools.commands.bench.transport import BUFFER_SIZE_TAGS, without_buffer_sizes

    def values(path, tag):
        return [e.text for e in ElementTree.parse(path).getroot().iter() if e.tag.endswith(tag)]

    profile = package_path('config', 'fastdds_udp.xml')
    assert values(profile, 'type') == ['UDPv4']   # nothing that stays on one host
    assert values(profile, 'useBuiltinTransports') == ['false']
    for tag in BUFFER_SIZE_TAGS:
        assert [int(v) for v in values(profile, tag)] >= [8 * 2**20]
    stripped = without_buffer_sizes(profile, tmp_path / 'stripped.xml')
    assert all(values(stripped, tag) == [] for tag in BUFFER_SIZE_TAGS)
    assert values(stripped, 'maxMessageSize') == values(profile, 'maxMessageSize')
