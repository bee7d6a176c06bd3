"""Readers of the real RealSense RGB-D frames in ../shared/data (ViSP's tutorial and test data;
no ground truth): see each folder's SOURCE.txt for the formats."""
from __future__ import annotations

import json
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics

RBT_SEQUENCE = 'visp_images_rbt_sequence/sequence'
TUTORIAL = 'visp_realsense_tutorial_data'


def read_visp_depth_bin(path: Path) -> np.ndarray:
    """ViSP depth .bin: uint32 LE height, uint32 LE width, then height*width uint16 LE (mm)."""
    raw = path.read_bytes()
    height, width = np.frombuffer(raw[:8], '<u4')
    return np.frombuffer(raw[8:], '<u2').reshape(int(height), int(width))


def _first_camera(path: Path) -> str:
    """The text of the first camera of a ViSP .xml (the colour one when it holds several)."""
    return path.read_text().split('</camera>')[0]


def read_visp_K(path: Path) -> np.ndarray:
    """(3, 3) camera matrix of the first camera of a ViSP .xml (px, py, u0, v0)."""
    value = {k: float(re.search(fr'<{k}>([^<]+)</{k}>', _first_camera(path)).group(1))
             for k in ('px', 'py', 'u0', 'v0')}
    return np.array([[value['px'], 0, value['u0']], [0, value['py'], value['v0']], [0, 0, 1]])


def read_visp_camera_xml(path: Path) -> CameraIntrinsics:
    """Intrinsics of the first camera of a ViSP camera .xml that gives the image size."""
    first = _first_camera(path)
    width = int(re.search(r'<image_width>(\d+)', first).group(1))
    height = int(re.search(r'<image_height>(\d+)', first).group(1))
    return CameraIntrinsics(width=width, height=height, K=read_visp_K(path))


def rbt_sequence_frames(shared_data: Path) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """(name, depth_m (480, 640) float32, K (3, 3)) of ViSP's RBT desk sequence: depth aligned
    to colour, ``data`` of each npz in millimetres (its ``timestamp`` entry is not read: numpy
    cannot decode its dtype)."""
    folder = shared_data / RBT_SEQUENCE
    cam = json.loads((folder / 'cam.json').read_text())
    K = np.array([[cam['px'], 0, cam['u0']], [0, cam['py'], cam['v0']], [0, 0, 1]])
    for path in sorted(folder.glob('depth_image_*.npz')):
        with np.load(path, allow_pickle=False) as archive:
            depth = archive['data'].astype(np.float32) * np.float32(cam['depthScale'])
        yield path.stem, depth, K


def rbt_board_normal(shared_data: Path, name: str) -> np.ndarray:
    """(3,) the normal of the AprilTag board in the camera frame of RBT frame ``name``
    (``depth_image_NNNN``), from the sequence's tag detections (cMg, one per frame)."""
    tags = json.loads((shared_data / RBT_SEQUENCE / 'apriltag_data.json').read_text())
    cMg = np.asarray(tags['grid'][int(name.rsplit('_', 1)[1])], np.float64).reshape(4, 4)
    return cMg[:3, 2]


def tutorial_frames(shared_data: Path) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """(name, depth_m float32, K of the depth) of ViSP's tutorial captures: a D435 frame
    aligned to colour and an SR300 sequence whose depth is not (its depth camera's K)."""
    d435 = shared_data / TUTORIAL / 'computer-vision/d435_align_depth'
    yield ('d435', read_visp_depth_bin(d435 / 'depth_image_0000.bin') * np.float32(1e-3),
           read_visp_camera_xml(d435 / 'camera.xml').K)
    cube = shared_data / TUTORIAL / 'generic-rgbd-cube'
    K = read_visp_K(cube / 'model/cube/cube_depth.xml')
    for path in sorted((cube / 'data').glob('depth_image_*.bin')):
        yield f'cube {path.stem}', read_visp_depth_bin(path) * np.float32(1e-3), K
