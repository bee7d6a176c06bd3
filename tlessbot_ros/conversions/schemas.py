"""The ``ros2msg`` schema text of a message type (its .msg definition and every nested one,
concatenated as rosbag2 and Foxglove expect), for forwarding CDR bytes unchanged.

rosbags' Jazzy type store knows the standard packages; a package it lacks (vision_msgs,
tlessbot_interfaces) is read from the .msg files of its install prefix.
"""
from __future__ import annotations

import importlib
import re
from functools import lru_cache
from pathlib import Path
from typing import Any, cast


@lru_cache(maxsize=1)
def _store() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def package_share(package: str) -> Path:
    """``share/<package>`` of an installed interface package: from the ament index, else
    beside its Python module (``<prefix>/lib/pythonX.Y/site-packages/<package>``).

    Raises:
        ValueError: the package is not installed.
    """
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory(package))
    except (ImportError, LookupError, ValueError, KeyError, OSError):
        pass
    try:
        module = importlib.import_module(package)
    except ImportError:
        raise ValueError(f'interface package {package!r} is not installed') from None
    if module.__file__ is None:   # a namespace package: no module file to start from
        raise ValueError(f'interface package {package!r} has no share folder (a namespace '
                         'package without __init__.py)')
    return Path(module.__file__).resolve().parents[4] / 'share' / package


def message_definition(msgtype: str) -> str:
    """Concatenated ``ros2msg`` definition of ``msgtype`` ('pkg/msg/Name').

    Raises:
        ValueError: a type that neither the type store nor its package's files define.
    """
    from rosbags.typesys import get_types_from_msg
    from rosbags.typesys.base import TypesysError

    store = _store()
    for attempt in range(4):   # each missing package is registered once
        try:
            return cast(str, store.generate_msgdef(msgtype, ros_version=2)[0])
        except (TypesysError, KeyError) as error:
            found = re.search(r'([a-z][a-z0-9_]*)/msg/', str(error))
            missing = found.group(1) if found else msgtype.split('/')[0]
            folder = package_share(missing) / 'msg'
            files = sorted(folder.glob('*.msg'))
            if not files or attempt == 3:
                raise ValueError(f'no definition of {msgtype}: {error}') from None
            types: dict[str, Any] = {}
            for path in files:
                types.update(get_types_from_msg(path.read_text(), f'{missing}/msg/{path.stem}'))
            store.register(types)
    raise ValueError(f'no definition of {msgtype}')
