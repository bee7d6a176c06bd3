"""The rig of a parameter YAML, for the commands (simulate, evaluate --bag)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, CameraMount, Rig, rig_from_params
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path, load_ros_params


def load_rig(config: Path | None = None, *, width: int | None = None,
             height: int | None = None) -> Rig:
    """The rig of a parameter YAML (``config/cell.yaml`` when None), with intrinsics rescaled
    to ``width`` x ``height`` (pixels; give both to change the aspect ratio)."""
    path = config or default_config_path()
    try:
        rig = rig_from_params(load_ros_params(path))
    except ValueError as error:
        raise TlessbotError(f'{path}: {error}') from None
    if width is None and height is None:
        return rig
    cameras = {}
    for name, cam in rig.cameras.items():
        w = width or cam.intrinsics.width
        h = height or cam.intrinsics.height
        sx, sy = w / cam.intrinsics.width, h / cam.intrinsics.height
        if abs(sx - sy) > 1e-6 and (width is None or height is None):
            raise TlessbotError('give both --width and --height when changing the aspect ratio')
        K = np.array(cam.intrinsics.K, dtype=np.float64)
        s = min(sx, sy)  # keep square pixels; a wider/taller image adds field of view
        K[0, 0] *= s
        K[1, 1] *= s
        K[0, 2] = (K[0, 2] + 0.5) * s - 0.5 + (w - cam.intrinsics.width * s) / 2
        K[1, 2] = (K[1, 2] + 0.5) * s - 0.5 + (h - cam.intrinsics.height * s) / 2
        cameras[name] = CameraMount(name, CameraIntrinsics(width=w, height=h, K=K),
                                    cam.T_world_camera)
    return Rig(cameras=cameras, world_frame=rig.world_frame)


# ----------------------------------------------------------------------- writing a rig
EXTRINSIC_KEYS = ('position_m', 'look_at_m', 'up')


def _number(value: float) -> str:
    """A coordinate as YAML writes it: 6 decimals (1 um; 1 urad for a unit vector), no -0."""
    text = f'{value:.6f}'.rstrip('0')
    text = text + '0' if text.endswith('.') else text
    return '0.0' if text in ('-0.0', '-0') else text


def _key_of(line: str) -> tuple[int, str, str] | None:
    """(indent, key, rest after the colon) of a ``key: ...`` mapping line, else None."""
    stripped = line.lstrip(' ')
    if not stripped or stripped.startswith(('#', '-')) or ':' not in stripped:
        return None
    key, _, rest = stripped.partition(':')
    if not key or ' ' in key.strip() or not (rest == '' or rest[0] in ' \n'):
        return None
    return len(line) - len(stripped), key.strip().strip('\'"'), rest


def replace_rig_extrinsics(text: str, rig: Rig, *, note: str = '') -> str:
    """A parameter YAML's text with the ``rig.<camera>.{position_m, look_at_m, up}`` values of
    every camera of ``rig`` replaced (wherever the ``rig`` block is); every other line, comment
    and value is kept as it is.

    Args:
        text: the YAML (e.g. config/cell.yaml).
        rig: the cameras to write (:func:`~tlessbot_ros.core.common.look_at_params` gives the
            values).
        note: a comment put after each replaced value (e.g. where it came from).

    Raises:
        TlessbotError: a camera of ``rig`` or one of its keys is not in the YAML (the file
            must name them, as config/cell.yaml does).
    """
    from tlessbot_ros.core.common import look_at_params

    values = {}
    for name, mount in rig.cameras.items():
        for key, value in zip(EXTRINSIC_KEYS, look_at_params(mount.T_world_camera)):
            values[(name, key)] = '[' + ', '.join(_number(v) for v in value) + ']'
    lines = text.splitlines(keepends=True)
    out: list[str] = []
    path: list[tuple[int, str]] = []   # (indent, key) of the mapping keys enclosing a line
    done = set()
    k = 0
    while k < len(lines):
        line = lines[k]
        found = _key_of(line)
        if found is None:
            out.append(line)
            k += 1
            continue
        indent, key, rest = found
        while path and path[-1][0] >= indent:
            path.pop()
        path.append((indent, key))
        names = [p[1] for p in path]
        target = (names[-2], key) if len(names) >= 3 and names[-3] == 'rig' else None
        if target not in values:
            out.append(line)
            k += 1
            continue
        # the old value: inline on this line, or a block sequence on the lines below
        k += 1
        if rest.split('#', 1)[0].strip() == '':
            while k < len(lines) and (lines[k].strip() == '' or (
                    lines[k].lstrip().startswith('-') and
                    len(lines[k]) - len(lines[k].lstrip(' ')) >= indent)):
                k += 1
        comment = f'  # {note}' if note else ''
        out.append(f'{" " * indent}{key}: {values[target]}{comment}\n')
        done.add(target)
    missing = sorted(set(values) - done)
    if missing:
        raise TlessbotError('the YAML has no ' + ', '.join(
            f'rig.{name}.{key}' for name, key in missing) + ': write the rig into a copy of '
            'config/cell.yaml, which names them')
    return ''.join(out)


def write_rig(config: Path, rig: Rig, out: Path, *, note: str = '') -> None:
    """Write ``config`` to ``out`` with ``rig``'s extrinsics (:func:`replace_rig_extrinsics`),
    and check that the file written reads back as ``rig`` (1 um, 1 urad).

    Raises:
        TlessbotError: as :func:`replace_rig_extrinsics`, or the check fails.
    """
    try:
        text = Path(config).read_text(encoding='utf-8')
    except OSError as error:
        raise TlessbotError(f'cannot read {config}: {error}') from None
    Path(out).write_text(replace_rig_extrinsics(text, rig, note=note), encoding='utf-8')
    written = load_rig(Path(out))
    for name, mount in rig.cameras.items():
        if not np.allclose(written[name].T_world_camera, mount.T_world_camera, atol=1e-5):
            raise TlessbotError(f'{out}: camera {name} does not read back as written')
