"""BOP-format datasets: write simulated views, read any BOP split.

Layout (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md)::

    <root>/<split>/<scene_id:06d>/scene_camera.json   per im_id: cam_K, depth_scale,
                                                       cam_R_w2c, cam_t_w2c (mm)
                                  scene_gt.json        per im_id: [{obj_id, cam_R_m2c, cam_t_m2c}]
                                  scene_gt_info.json   per im_id: [{bbox_obj, bbox_visib,
                                                       px_count_all, px_count_visib, visib_fract}]
                                  rgb/{im_id:06d}.png, depth/{im_id:06d}.png (uint16),
                                  mask_visib/{im_id:06d}_{gt_idx:06d}.png

Rotations are row-major 3x3 lists, translations millimetres; ``depth_mm = value * depth_scale``.
A two-view dataset has splits ``test_top`` and ``test_side`` with the same scene and image ids.
In memory everything is in metres.
"""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, invert_transform, nearest_rotation
from tlessbot_ros.errors import DatasetError

if TYPE_CHECKING:
    from tlessbot_ros.sim.simulator import SimulatedView

_SCENE_FILES = ('scene_camera.json', 'scene_gt.json', 'scene_gt_info.json')


@dataclass
class BopGroundTruth:
    """One annotated object instance of a BOP image (metres)."""

    obj_id: int
    T_camera_object: np.ndarray
    bbox_visib: tuple[int, int, int, int] | None
    visib_fract: float | None
    mask: np.ndarray | None = None
    bbox_obj: tuple[int, int, int, int] | None = None
    px_count_visib: int | None = None


@dataclass
class BopImage:
    """One image of a BOP split.

    Attributes:
        rgb: (H, W, 3) uint8 RGB (grey images are replicated to 3 channels), or None.
        depth_m: (H, W) float32 metres, NaN where invalid, or None if the split has no depth.
        intrinsics: from ``cam_K`` and the image size.
        T_world_camera: (4, 4) from ``cam_R_w2c`` / ``cam_t_w2c``, or None if absent.
        gt: annotated objects (empty if the split has no scene_gt.json).
    """

    split: str
    scene_id: int
    im_id: int
    rgb: np.ndarray | None
    depth_m: np.ndarray | None
    intrinsics: CameraIntrinsics
    T_world_camera: np.ndarray | None
    gt: list[BopGroundTruth] = field(default_factory=list)
    depth_scale: float = 1.0


def _pose_mm(T: np.ndarray) -> tuple[list[float], list[float]]:
    R = np.asarray(T[:3, :3], dtype=np.float64)
    return ([float(x) for x in R.ravel()], [float(x) * 1000.0 for x in T[:3, 3]])


def _pose_from_mm(R: Any, t: Any) -> np.ndarray:
    """(4, 4) pose in metres; an annotated R a little off SO(3) is projected onto it (angles
    are then those of a rotation, as BOP's own scoring takes them); a far one is kept as is."""
    T = np.eye(4)
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    projected = nearest_rotation(R)
    T[:3, :3] = R if projected is None else projected
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3) / 1000.0
    return T


def _write_png(path: Path, image: np.ndarray) -> None:
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    if not cv2.imwrite(str(path), image):
        raise DatasetError(f'cannot write {path}')


class BopWriter:
    """Write views into ``<root>/<split>/``; JSON files are written by :meth:`close` (or
    whenever the scene id changes). Use as a context manager."""

    def __init__(self, root: str | Path, split: str, *, depth_scale: float = 1.0,
                 write_masks: bool = True) -> None:
        self.root = Path(root)
        self.split = split
        self.depth_scale = float(depth_scale)
        self.write_masks = write_masks
        self._scene_id: int | None = None
        self._data: dict[str, dict[str, Any]] = {}
        (self.root / split).mkdir(parents=True, exist_ok=True)

    def __enter__(self) -> BopWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _scene_dir(self, scene_id: int) -> Path:
        return self.root / self.split / f'{scene_id:06d}'

    def _switch(self, scene_id: int) -> None:
        if scene_id == self._scene_id:
            return
        self.flush()
        self._scene_id = scene_id
        folder = self._scene_dir(scene_id)
        self._data = {}
        for name in _SCENE_FILES:  # appending to an existing scene keeps its images
            path = folder / name
            self._data[name] = json.loads(path.read_text()) if path.is_file() else {}
        for sub in ('rgb', 'depth', 'mask_visib'):
            (folder / sub).mkdir(parents=True, exist_ok=True)

    def add(self, scene_id: int, im_id: int, view: SimulatedView) -> None:
        """Add one view as image ``im_id`` of scene ``scene_id``."""
        self._switch(int(scene_id))
        folder = self._scene_dir(int(scene_id))
        key = str(int(im_id))
        T_cw = invert_transform(view.T_world_camera)
        R, t = _pose_mm(T_cw)
        self._data['scene_camera.json'][key] = {
            'cam_K': [float(x) for x in np.asarray(view.intrinsics.K).ravel()],
            'depth_scale': self.depth_scale, 'cam_R_w2c': R, 'cam_t_w2c': t}
        gts, infos = [], []
        for idx, gt in enumerate(view.gt):
            R, t = _pose_mm(gt.T_camera_object)
            gts.append({'cam_R_m2c': R, 'cam_t_m2c': t, 'obj_id': int(gt.obj_id)})
            infos.append({'bbox_obj': [int(x) for x in gt.bbox_obj],
                          'bbox_visib': [int(x) for x in gt.bbox_visib],
                          'px_count_all': int(gt.px_count_all),
                          'px_count_valid': int(np.count_nonzero(
                              gt.mask_visib & (view.depth_mm > 0))),
                          'px_count_visib': int(gt.px_count_visib),
                          'visib_fract': float(gt.visib_fract)})
            if self.write_masks:
                _write_png(folder / 'mask_visib' / f'{int(im_id):06d}_{idx:06d}.png',
                           gt.mask_visib.astype(np.uint8) * 255)
        self._data['scene_gt.json'][key] = gts
        self._data['scene_gt_info.json'][key] = infos
        _write_png(folder / 'rgb' / f'{int(im_id):06d}.png', view.rgb)
        depth = view.depth_mm.astype(np.float64) / self.depth_scale
        _write_png(folder / 'depth' / f'{int(im_id):06d}.png',
                   np.clip(np.rint(depth), 0, 65535).astype(np.uint16))

    def flush(self) -> None:
        """Write the current scene's JSON files."""
        if self._scene_id is None:
            return
        folder = self._scene_dir(self._scene_id)
        for name, data in self._data.items():
            ordered = {k: data[k] for k in sorted(data, key=int)}
            (folder / name).write_text(json.dumps(ordered, indent=1), encoding='utf-8')

    def close(self) -> None:
        self.flush()
        self._scene_id = None


def write_camera_json(path: str | Path, intrinsics: CameraIntrinsics,
                      depth_scale: float = 1.0) -> None:
    """BOP ``camera.json`` (fx, fy, cx, cy, width, height, depth_scale)."""
    data = {'cx': intrinsics.cx, 'cy': intrinsics.cy, 'fx': intrinsics.fx, 'fy': intrinsics.fy,
            'width': int(intrinsics.width), 'height': int(intrinsics.height),
            'depth_scale': float(depth_scale)}
    Path(path).write_text(json.dumps(data, indent=1), encoding='utf-8')


# --- reading ------------------------------------------------------------------------------------

def _is_scene_dir(path: Path) -> bool:
    return path.is_dir() and path.name.isdigit() and (path / 'scene_camera.json').is_file()


def list_splits(root: str | Path) -> list[str]:
    """Names of the split folders of a BOP dataset root (those holding scene folders)."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f'dataset folder not found: {root}')
    splits = sorted(p.name for p in root.iterdir()
                    if p.is_dir() and any(_is_scene_dir(s) for s in p.iterdir()))
    if not splits:
        raise DatasetError(f'{root} is not a BOP dataset (no <split>/<scene_id>/'
                           'scene_camera.json)')
    return splits


def _load_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as error:
        raise DatasetError(f'cannot read {path}: {error}') from None


def _image_path(folder: Path, im_id: int) -> Path | None:
    for suffix in ('.png', '.jpg', '.jpeg', '.tif'):
        path = folder / f'{im_id:06d}{suffix}'
        if path.is_file():
            return path
    return None


def _read_image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise DatasetError(f'cannot read image {path}')
    return image


def read_split(root: str | Path, split: str, *, limit: int | None = None,
               load_masks: bool = True) -> Iterator[BopImage]:
    """Iterate over the images of ``<root>/<split>`` in (scene_id, im_id) order.

    Raises:
        DatasetError: missing split, not a BOP layout, or unreadable files.
    """
    root = Path(root)
    folder = root / split
    if not folder.is_dir():
        available = ', '.join(list_splits(root)) if root.is_dir() else ''
        raise DatasetError(f'{root} has no split {split!r}'
                           + (f' (available: {available})' if available else ''))
    scenes = sorted((p for p in folder.iterdir() if _is_scene_dir(p)), key=lambda p: int(p.name))
    if not scenes:
        raise DatasetError(f'{folder} is not a BOP split (no <scene_id>/scene_camera.json)')
    count = 0
    for scene_dir in scenes:
        cameras = _load_json(scene_dir / 'scene_camera.json')
        gts = _load_json(scene_dir / 'scene_gt.json')
        infos = _load_json(scene_dir / 'scene_gt_info.json')
        for key in sorted(cameras, key=int):
            if limit is not None and count >= limit:
                return
            yield _read_image_entry(split, scene_dir, int(key), cameras[key], gts.get(key, []),
                                    infos.get(key, []), load_masks)
            count += 1


def _read_image_entry(split: str, scene_dir: Path, im_id: int, cam: dict, gts: list,
                      infos: list, load_masks: bool) -> BopImage:
    try:
        K = np.asarray(cam['cam_K'], dtype=np.float64).reshape(3, 3)
    except (KeyError, ValueError):
        raise DatasetError(f'{scene_dir / "scene_camera.json"}: image {im_id} has no valid '
                           'cam_K') from None
    depth_scale = float(cam.get('depth_scale', 1.0))
    rgb = None
    rgb_path = _image_path(scene_dir / 'rgb', im_id) or _image_path(scene_dir / 'gray', im_id)
    if rgb_path is not None:
        image = _read_image(rgb_path, cv2.IMREAD_COLOR)
        rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    depth_m = None
    depth_path = _image_path(scene_dir / 'depth', im_id)
    if depth_path is not None:
        raw = _read_image(depth_path, cv2.IMREAD_UNCHANGED).astype(np.float32)
        depth_m = np.where(raw > 0, raw * np.float32(depth_scale / 1000.0), np.nan)
        depth_m = depth_m.astype(np.float32)
    shape = rgb.shape[:2] if rgb is not None else (depth_m.shape if depth_m is not None else None)
    if shape is None:
        height, width = int(round(2 * K[1, 2] + 1)), int(round(2 * K[0, 2] + 1))
    else:
        height, width = shape
    intrinsics = CameraIntrinsics(width=width, height=height, K=K)
    T_world_camera = None
    if 'cam_R_w2c' in cam and 'cam_t_w2c' in cam:
        T_world_camera = invert_transform(_pose_from_mm(cam['cam_R_w2c'], cam['cam_t_w2c']))
    gt_list = []
    for idx, entry in enumerate(gts):
        info = infos[idx] if idx < len(infos) else {}
        mask = None
        if load_masks:
            mask_path = scene_dir / 'mask_visib' / f'{im_id:06d}_{idx:06d}.png'
            if mask_path.is_file():
                mask = _read_image(mask_path, cv2.IMREAD_GRAYSCALE) > 0
        bbox = info.get('bbox_visib')
        bbox_obj = info.get('bbox_obj')
        gt_list.append(BopGroundTruth(
            obj_id=int(entry['obj_id']),
            T_camera_object=_pose_from_mm(entry['cam_R_m2c'], entry['cam_t_m2c']),
            bbox_visib=tuple(int(x) for x in bbox) if bbox is not None else None,
            visib_fract=float(info['visib_fract']) if 'visib_fract' in info else None,
            mask=mask, bbox_obj=tuple(int(x) for x in bbox_obj) if bbox_obj else None,
            px_count_visib=int(info['px_count_visib']) if 'px_count_visib' in info else None))
    return BopImage(split, int(scene_dir.name), im_id, rgb, depth_m, intrinsics, T_world_camera,
                    gt_list, depth_scale)


def copy_with_extrinsics(source: str | Path, target: str | Path,
                         change: Callable[[np.ndarray], np.ndarray | None]) -> int:
    """Copy a BOP dataset with every image's camera pose changed, e.g. removed to evaluate
    one view without extrinsics (``change=lambda T: None``) or moved to play a rig that was
    measured wrong. Images are hard-linked (copied across file systems); only each
    ``scene_camera.json`` is rewritten.

    Args:
        change: maps an image's ``T_world_camera`` (4, 4) to the one to write, or to None to
            drop its ``cam_R_w2c`` / ``cam_t_w2c``.

    Returns:
        the number of camera entries changed.

    Raises:
        DatasetError: ``source`` is not a BOP dataset or ``target`` exists.
    """
    source, target = Path(source), Path(target)
    list_splits(source)   # raises on a folder that is not a BOP dataset
    if target.exists():
        raise DatasetError(f'{target} exists; give a new folder')
    changed = 0
    for folder, _, files in os.walk(source):
        out = target / Path(folder).relative_to(source)
        out.mkdir(parents=True, exist_ok=True)
        for name in files:
            if name == 'scene_camera.json':
                cameras = _load_json(Path(folder) / name)
                for entry in cameras.values():
                    changed += _change_extrinsics(entry, change)
                (out / name).write_text(json.dumps(cameras, indent=1), encoding='utf-8')
                continue
            try:
                os.link(Path(folder) / name, out / name)
            except OSError:
                shutil.copy2(Path(folder) / name, out / name)
    return changed


def _change_extrinsics(entry: dict, change: Callable[[np.ndarray], np.ndarray | None]) -> int:
    """Apply ``change`` to one scene_camera.json entry in place; 1 if it had extrinsics."""
    if 'cam_R_w2c' not in entry or 'cam_t_w2c' not in entry:
        return 0
    T = change(invert_transform(_pose_from_mm(entry.pop('cam_R_w2c'), entry.pop('cam_t_w2c'))))
    if T is not None:
        entry['cam_R_w2c'], entry['cam_t_w2c'] = _pose_mm(invert_transform(np.asarray(T)))
    return 1
