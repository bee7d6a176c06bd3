"""The part's crops in labelled capture bags, cut out by the localiser (``tlessbot train
--captures``, ``tlessbot bench captures``).

Each frame of each camera of a capture bag (:mod:`tlessbot_ros.io.capture`) is segmented as
the localiser segments a view (:func:`tlessbot_ros.core.localise.segment`, with the depth cue in
the view's table frame, and the bag's empty-table background when it has one); the largest
region is the part. Its descriptor is the one the classifier computes at run time
(``Classifier.describe`` for a model; ``describe_regions`` and the shape features for
training), so capture crops and CAD renders feed one feature space.
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.errors import BagError

MIN_PART_PX = 100   # a smaller largest region is no view of the part (as training scenes)


@dataclass
class CaptureCrop:
    """The part in one camera's frame of a capture bag."""

    obj_id: int
    camera: str
    frame: int
    stamp_ns: int
    rgb: np.ndarray
    mask: np.ndarray
    box: tuple[int, int, int, int]
    depth_m: np.ndarray | None
    K: np.ndarray
    T_world_camera: np.ndarray | None


def _backgrounds(bag: Path, cameras: Sequence[str]) -> dict[str, np.ndarray]:
    """Per camera, the first colour image of the label's background bag (if any)."""
    from tlessbot_ros.io.capture import read_capture_label
    from tlessbot_ros.tools.support.calibration import bag_frames

    name = read_capture_label(bag).background
    if not name:
        return {}
    path = (bag / name) if not Path(name).is_absolute() else Path(name)
    for frame in bag_frames(path, cameras=cameras, colour=True):
        return dict(frame.rgb)
    raise BagError(f'background bag {path} holds no frames of {list(cameras)}')


def capture_crops(bag: str | Path, *, config: Path | None = None, every: int = 1,
                  min_px: int = MIN_PART_PX, skipped: list | None = None
                  ) -> Iterator[CaptureCrop]:
    """The part's crops of a capture bag, frame by frame, camera by camera.

    Args:
        bag: capture bag folder (with ``capture.yaml``).
        config: the cell's parameter YAML (its rig gives each camera's table frame, checked
            against the table seen in the depth); default ``config/cell.yaml``.
        every: use every n-th frame.
        skipped: appended (frame, camera) where the localiser found no part.
    """
    from tlessbot_ros.core.common import CameraIntrinsics
    from tlessbot_ros.core.localise import segment
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.io.capture import read_capture_label
    from tlessbot_ros.tools.support.calibration import bag_frames
    from tlessbot_ros.tools.support.rig import load_rig

    bag = Path(bag)
    label = read_capture_label(bag)
    rig = load_rig(config)
    pipeline = PerceptionPipeline(rig=rig)
    backgrounds = _backgrounds(bag, label.cameras)
    for k, frame in enumerate(bag_frames(bag, cameras=label.cameras, colour=True)):
        if k % every:
            continue
        for camera in label.cameras:
            rgb, depth = frame.rgb[camera], frame.depth[camera]
            h, w = rgb.shape[:2]
            view = ViewInput(rgb, depth, CameraIntrinsics(width=w, height=h, K=frame.K[camera]),
                             rig[camera].T_world_camera if camera in rig.cameras else None,
                             backgrounds.get(camera))
            T_world_camera = pipeline.table_frame(camera, view).T_world_camera
            seg = segment(rgb, background=view.background,
                          depth_m=depth if T_world_camera is not None else None,
                          intrinsics=view.intrinsics if T_world_camera is not None else None,
                          T_world_camera=T_world_camera, split_by_depth=False,
                          params=pipeline.segmentation)
            if seg.count == 0 or seg.areas.max() < min_px:
                if skipped is not None:
                    skipped.append((k, camera))
                continue
            part = int(np.argmax(seg.areas))
            x, y, bw, bh = (int(v) for v in seg.boxes[part])
            yield CaptureCrop(label.obj_id, camera, k, frame.stamp_ns, rgb,
                              seg.labels == part + 1, (x, y, bw, bh), depth, frame.K[camera],
                              T_world_camera)


def augmented(crop: CaptureCrop, copies: int, seed: int) -> Iterator[CaptureCrop]:
    """``copies`` shear / zoom / occlusion copies of a crop, as the CAD turntable makes them
    (the paper's augmentation of its captures; :func:`tlessbot_ros.sim.turntable.augment_view`,
    the depth warped with the image and the camera matrix with it)."""
    from dataclasses import replace

    from tlessbot_ros.core.common import mask_box
    from tlessbot_ros.sim.turntable import TurntableParams, augment_view

    if copies < 1 or crop.depth_m is None:
        return
    rng = np.random.default_rng([seed, crop.obj_id, crop.frame, *crop.camera.encode()])
    for _ in range(copies):
        rgb, mask, depth, K = augment_view(crop.rgb, crop.mask, TurntableParams(), rng,
                                           crop.depth_m, crop.K)
        if mask.sum() >= MIN_PART_PX:
            yield replace(crop, rgb=rgb, mask=mask, box=tuple(int(v) for v in mask_box(mask)),
                          depth_m=depth, K=K)


def capture_features(bags: Sequence[Path], hog, shape=None, *, config: Path | None = None,
                     every: int = 1, copies: int = 0, seed: int = 0, progress: bool = True
                     ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Training descriptors of the capture bags' crops (and ``copies`` augmented copies of
    each), as CAD training computes them: ((N, D) float32 HOG (+ shape, NaN where the depth is
    unusable), (N,) int64 ids, counts).

    Raises:
        BagError: a bag that is no capture bag, or bags without a single crop.
    """
    from tqdm import tqdm

    from tlessbot_ros.core.recognise import (
        describe_regions,
        region_points_world,
        shape_features_batch,
    )

    features, labels, skipped = [], [], []
    for bag in bags:
        crops = capture_crops(bag, config=config, every=every, skipped=skipped)
        for found in tqdm(crops, desc=f'captures {Path(bag).name}', unit='crop',
                          disable=not progress):
            for crop in (found, *augmented(found, copies, seed)):
                row = describe_regions(crop.rgb, [crop.box], [crop.mask], params=hog)
                if shape is not None:
                    points = [] if crop.T_world_camera is None or crop.depth_m is None else [
                        region_points_world(crop.depth_m, crop.mask, crop.K,
                                            crop.T_world_camera, box=crop.box)]
                    values = shape_features_batch(points, params=shape) if points else \
                        np.full((1, shape.feature_dim), np.nan, np.float32)
                    row = np.hstack([row, values])
                features.append(row)
                labels.append(crop.obj_id)
    if not labels:
        raise BagError(f'the localiser found no part in the capture bags {[str(b) for b in bags]}')
    return (np.vstack(features).astype(np.float32), np.asarray(labels, np.int64),
            {'capture_crops': len(labels), 'capture_skipped': len(skipped)})


def add_captures(bags: Sequence[Path], hog, shape, features: np.ndarray, labels: np.ndarray,
                 source: dict, *, config: Path | None = None, every: int = 1,
                 copies: int = 0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``features`` / ``labels`` (possibly empty: captures alone) with the capture bags' crops
    appended; ``source`` (the model's training info) says what was added."""
    if every < 1:
        raise BagError(f'--capture-every must be at least 1, got {every}')
    if copies < 0:
        raise BagError(f'--capture-augmentations must be >= 0, got {copies}')
    more, more_labels, counts = capture_features(bags, hog, shape, config=config, every=every,
                                                 copies=copies, seed=seed)
    if len(labels):
        more_labels = np.concatenate([labels, more_labels])
        more = np.vstack([features, more])
    source.setdefault('source', 'captures')
    source.update(captures=[Path(b).name for b in bags], capture_every=every,
                  capture_augmentations=copies, **counts)
    return more, more_labels
