"""ROS 2 parameter YAML files (``node: ros__parameters: ...`` / ``/**``) read without ROS."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from tlessbot_ros.errors import TlessbotError


def _flatten(tree: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def load_ros_params(path: str | Path, node_name: str | None = None) -> dict[str, Any]:
    """Flat parameters (dotted names, as rcl flattens them) that ``node_name`` would get.

    The wildcard section ``/**`` applies first, then ``node_name`` or ``/node_name``.
    """
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text(encoding='utf-8')) or {}
    except FileNotFoundError:
        raise TlessbotError(f'parameter file not found: {path}') from None
    except yaml.YAMLError as error:
        raise TlessbotError(f'parameter file {path} is not valid YAML: {error}') from None
    params: dict[str, Any] = {}
    sections = ['/**']
    if node_name:
        sections += [node_name.lstrip('/'), '/' + node_name.lstrip('/')]
    for section in sections:
        body = document.get(section)
        if isinstance(body, dict):
            params.update(_flatten(body.get('ros__parameters', {}) or {}))
    return params


def package_path(*parts: str) -> Path:
    """A file of this package outside the Python modules (config/, bags/): the source tree's,
    else the copy a colcon install put in share/tlessbot_ros/."""
    source = Path(__file__).resolve().parents[2].joinpath(*parts)
    if source.exists():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory('tlessbot_ros')).joinpath(*parts)
    except (ImportError, LookupError):
        return source


def default_config_path() -> Path:
    """config/cell.yaml of this package."""
    return package_path('config', 'cell.yaml')
