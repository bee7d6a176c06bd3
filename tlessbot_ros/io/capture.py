"""The label of a capture bag: which part it shows, with which cameras, at which plate angles.

``tlessbot capture`` (and the simulator's capture session) writes ``capture.yaml`` into the bag
folder, beside rosbag2's ``metadata.yaml``::

    part: obj_05            # the part's name (its CAD file's stem)
    obj_id: 5               # its id in the classifier
    cameras: [top, side]    # the cameras recorded (their topics: /NAME/color/image_raw, ...)
    background: ''          # optional: a bag of the empty table, relative to this folder
    frames:                 # optional: per whole frame (every topic recorded), its stamp
      - {stamp_ns: 1700000000000000000, turntable_deg: 0.0}   # and the plate angle

YAML written and read with ``yaml.safe_*`` (nothing is unpickled).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.errors import BagError

LABEL_FILE = 'capture.yaml'
_PART_NAME = re.compile(r'^obj_(\d+)$')


def part_id(name: str) -> int:
    """The id of a part named ``obj_NN`` (NN > 0).

    Raises:
        BagError: another name (give the id explicitly then).
    """
    found = _PART_NAME.match(name)
    if not found or int(found.group(1)) < 1:
        raise BagError(f'part name {name!r} is not obj_NN; give its id (--obj-id)')
    return int(found.group(1))


@dataclass
class CaptureLabel:
    """What a capture bag shows (see the module docstring)."""

    part: str
    obj_id: int
    cameras: list[str]
    frames: list[dict] = field(default_factory=list)
    background: str = ''

    def __post_init__(self) -> None:
        if self.obj_id < 1:
            raise BagError(f'capture label: obj_id must be a positive id, got {self.obj_id}')
        if not self.cameras:
            raise BagError('capture label: no cameras')

    def write(self, bag: str | Path) -> Path:
        """Write ``<bag>/capture.yaml``; returns its path."""
        import yaml

        path = Path(bag) / LABEL_FILE
        data = {'part': self.part, 'obj_id': int(self.obj_id), 'cameras': list(self.cameras),
                'background': self.background,
                'frames': [{'stamp_ns': int(f['stamp_ns']),
                            **({'turntable_deg': round(float(f['turntable_deg']), 4)}
                               if f.get('turntable_deg') is not None else {})}
                           for f in self.frames]}
        path.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None),
                        encoding='utf-8')
        return path

    def turntable_deg(self) -> dict[int, float]:
        """{header stamp (ns): plate angle (degrees)} of the frames that have one."""
        return {int(f['stamp_ns']): float(f['turntable_deg']) for f in self.frames
                if f.get('turntable_deg') is not None}


def read_capture_label(bag: str | Path) -> CaptureLabel:
    """The label of a capture bag folder.

    Raises:
        BagError: no ``capture.yaml`` in the folder, or one that is not a capture label.
    """
    import yaml

    path = Path(bag) / LABEL_FILE
    if not path.is_file():
        raise BagError(f'{bag} has no {LABEL_FILE}: not a capture bag (record one with '
                       'tlessbot capture)')
    try:
        data = yaml.safe_load(path.read_text(encoding='utf-8'))
        return CaptureLabel(part=str(data['part']), obj_id=int(data['obj_id']),
                            cameras=[str(c) for c in data['cameras']],
                            frames=list(data.get('frames') or []),
                            background=str(data.get('background') or ''))
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as error:
        raise BagError(f'{path}: not a capture label ({error})') from None
