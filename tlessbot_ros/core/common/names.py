"""Part names: a part has an integer id in code and a name in everything a user sees.

The name is its CAD file's stem (``bracket_l.stl`` -> ``bracket_l``); the T-LESS parts keep
``obj_05``. Names go into topic names (``/objects/<name>/pose``), frame ids, marker texts and
reports, so each must be a valid ROS name token: a letter first, then letters, digits and
single underscores (ROS 2 design, "Topic and Service name mapping to DDS",
https://design.ros2.org/articles/topic_and_service_names.html).
"""
from __future__ import annotations

import re
from collections.abc import Mapping

from tlessbot_ros.errors import PartNameError

_TOKEN = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_DEFAULT = re.compile(r'^obj_(\d+)$')


def default_part_name(obj_id: int) -> str:
    """The name of a part that has none of its own: ``obj_05`` (T-LESS, BOP ids)."""
    return f'obj_{int(obj_id):02d}'


def part_name(obj_id: int, names: Mapping[int, str] | None = None) -> str:
    """The name of part ``obj_id``: ``names[obj_id]`` when given and listed, else
    :func:`default_part_name`."""
    if names is not None and int(obj_id) in names:
        return names[int(obj_id)]
    return default_part_name(obj_id)


def part_id(name: str, names: Mapping[int, str] | None = None) -> int:
    """The id of the part called ``name`` (the inverse of :func:`part_name`).

    Raises:
        PartNameError: no part of that name.
    """
    if names is not None:
        for obj_id, listed in names.items():
            if listed == name:
                return int(obj_id)
    match = _DEFAULT.match(name)
    if match and (names is None or int(match.group(1)) not in names):
        return int(match.group(1))
    known = ', '.join(sorted(names.values())) if names else 'obj_NN'
    raise PartNameError(f'no part named {name!r} (known: {known})')


def suggest_part_name(stem: str) -> str:
    """A valid name close to ``stem``: other characters become ``_``, runs of ``_`` collapse,
    and a leading digit gets a ``part_`` prefix (``'M6 bolt-2'`` -> ``'M6_bolt_2'``)."""
    name = re.sub(r'_+', '_', re.sub(r'[^A-Za-z0-9_]', '_', stem)).strip('_')
    if not name:
        return 'part'
    return name if name[0].isalpha() else f'part_{name}'


def check_part_name(name: str, *, source: str = '') -> str:
    """``name`` itself if it can name topics and frames.

    Raises:
        PartNameError: with the name to rename ``source`` (a file) to.
    """
    if _TOKEN.match(name) and '__' not in name and not name.endswith('_'):
        return name
    where = f' (from {source})' if source else ''
    suffix = source[source.rfind('.'):] if '.' in source else ''
    raise PartNameError(
        f'part name {name!r}{where} cannot name a ROS topic or frame: use a letter first, then '
        f'letters, digits and single underscores; rename the file to '
        f'{suggest_part_name(name)}{suffix}')


def check_part_names(names: Mapping[int, str]) -> dict[int, str]:
    """``names`` as a dict after checking each one and that no two are equal.

    Raises:
        PartNameError: an invalid or repeated name.
    """
    seen: dict[str, int] = {}
    for obj_id, name in names.items():
        check_part_name(name)
        if name in seen:
            raise PartNameError(f'parts {seen[name]} and {obj_id} are both named {name!r}')
        seen[name] = int(obj_id)
    return {int(k): v for k, v in names.items()}
