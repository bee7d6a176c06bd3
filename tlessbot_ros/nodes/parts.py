"""The parts a stage node knows: the packaged T-LESS set, or a parts folder (``parts_path``).

A parts folder (``tlessbot parts build``) sets the defaults of the classifier's ``model_path``
and the pose estimator's ``templates_path`` and names the parts (topics, markers). It is
refused at start-up, in one line, when a file is missing or it was built for another rig.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from tlessbot_ros.core.label_views import view_order
from tlessbot_ros.io.parts import PartsFolder, open_parts_folder


def declare_parts(node: Any) -> PartsFolder | None:
    """Declare the read-only ``parts_path`` of a stage node and open its folder (None: the
    packaged parts).

    Raises:
        PartsFolderError: a missing file, a damaged manifest, or another rig's folder.
    """
    path = node.parameters.read_only('parts_path', '', (
        'Parts folder written by tlessbot parts build (empty: the packaged T-LESS parts); '
        'sets model_path, templates_path and the part names'))
    if not path:
        return None
    # its templates were seen from the side camera (or the one camera of a one-camera rig)
    side = view_order(node.cameras)[0]
    folder = open_parts_folder(Path(path).expanduser(), side_pose=node.extrinsics[side])
    node.get_logger().info(f'parts folder {folder.path}: '
                           f'{", ".join(folder.names.values())}')
    return folder
