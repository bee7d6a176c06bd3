"""Train the HOG + linear part classifier from CAD turntables or from real crops.

From CAD (the paper's §4 protocol, rendered): every part at --positions places on a turntable,
one view every --steps-deg degrees, each view plus --augmentations shear/zoom copies:

    tlessbot train --models ../shared/data/tless_models_cad_stl --out classifier.npz

From your own captures, laid out as DIR/<obj_id>/*.png (an alpha channel, if present, is the
part's silhouette; otherwise the whole image is the crop):

    tlessbot train --from-images DIR --out classifier.npz

--scenes N adds the crops of N simulated two-view table scenes (random parts, tables, lights
and materials, cut by their ground-truth visible masks; simulator seed --seed + 1000003, apart
from the seeds the benchmarks and the demo use). Scene crops carry what a turntable lacks:
neighbours, the real camera angles, both tables.

--kernel M learns on an RBF feature map of the descriptor (M landmarks, Nyström; see
tlessbot_ros.core.recognise.feature_map) instead of the descriptor itself. The packaged model:

    tlessbot train --models DIR --scenes 800 --kernel 4000 --kernel-axes 256 --hog-weight 0.3 \
        --classifier perceptron --average --epochs 20 --out classifier.npz

with the turntable rendering, is the named recipe ``--recipe packaged`` (RECIPES below). A
recipe sets these options; options given beside it win. The default, ``--recipe clutter``,
pastes each view among other parts on random tables and re-photographs it
(docs/recognition-real.md): it is the one that transfers to real images. ``--recipe hybrid``
takes the cluttered crops with the packaged model's scenes and learner; ``tlessbot parts
build`` uses it by default. ``--recipe hybrid-turntable`` adds the packaged recipe's
turntable views to hybrid's crops (``--turntable-crops``), cut by their boxes as the cluttered
crops are.

Several learners can share one rendering pass: --classifier all (or sgd,pa1) writes
<out>_<kind>.npz per learner.

--features ours (the default in CAD mode) appends metric shape features from the rendered,
D415-noised depth of each view (heights above the plate, footprint, height map; see
tlessbot_ros.core.recognise.shape) to the HOG; --features paper keeps the paper's HOG
only. --smoothed-share F renders a share F of the turntable views and of the --scenes with
the stereo-like 'smoothed' depth a real RealSense gives (tlessbot_ros.sim.stereo_depth)
instead of the per-pixel noise, so the shape features are also learnt as a real camera's
depth shows them.
Image folders have no depth, so they always give paper-feature models.

From labelled capture bags (tlessbot capture; docs/capture.md), alone or mixed with CAD
renders: the localiser cuts the part out of every frame, described as CAD crops are:

    tlessbot train --captures captures/obj_* [--models DIR --ids ...] \
        [--capture-augmentations 3] --out classifier.npz
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tlessbot_ros.core.recognise import (
    BACKGROUND_ID,
    KINDS,
    ClassifierParams,
    HogParams,
    ShapeParams,
    describe_regions,
    hog_features,
    normalise_crop,
    region_points_world,
    shape_features,
    train_classifier,
)
from tlessbot_ros.errors import DatasetError, TlessbotError
from tlessbot_ros.tools.support.scene_crops import scene_features
from tlessbot_ros.tools.support.train_clutter import (
    ClutterRecipe,
    clutter_features,
    recipe_with,
)

DEFAULT_STEP_DEG = 8.0
SCENE_SEED_OFFSET = 1_000_003   # training scenes never reuse a benchmark's simulator stream
DEFAULT_AUGMENTATIONS = 1
# Named recipes: option values (argparse destinations) that made a packaged model.
# 'recipe' is the CAD rendering a named recipe uses.
# The packaged model's scenes and learner; 'hybrid' takes them with the cluttered crops.
_PACKAGED_OPTIONS = {'scenes': 800, 'kernel': 4000, 'kernel_axes': 256, 'hog_weight': 0.3,
                     'classifier': 'perceptron', 'average': True, 'epochs': 20}
RECIPES = {
    'packaged': {'recipe': 'turntable', **_PACKAGED_OPTIONS},
    'hybrid': {'recipe': 'clutter', **_PACKAGED_OPTIONS},
    'hybrid-turntable': {'recipe': 'clutter', 'turntable_crops': True, **_PACKAGED_OPTIONS},
}
RECIPE_CHOICES = ('clutter', 'turntable', *sorted(RECIPES))   # what --recipe takes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group()
    source.add_argument('--models', type=Path, help='folder of obj_NN.stl|ply|obj CAD models')
    source.add_argument('--from-images', type=Path, metavar='DIR',
                        help='folder of <obj_id>/*.png crops (real turntable captures)')
    parser.add_argument('--captures', type=Path, nargs='+', metavar='BAG',
                        help='labelled capture bags (tlessbot capture): the part cut out by '
                             'the localiser in every frame; alone or with --models')
    parser.add_argument('--capture-every', type=int, default=1, metavar='N',
                        help='use every N-th frame of the capture bags (default 1)')
    parser.add_argument('--capture-augmentations', type=int, default=0, metavar='N',
                        help='shear/zoom copies of each capture crop, as the CAD turntable '
                             'makes them (paper: 3; default 0)')
    parser.add_argument('--config', type=Path,
                        help='the cell YAML of the capture bags (its rig; default '
                             'config/cell.yaml)')
    parser.add_argument('--out', type=Path, required=True, help='model file to write (.npz)')
    parser.add_argument('--classifier', default='sgd',
                        help=f"learner: {', '.join(KINDS)}, a comma list, or 'all' "
                             '(default: sgd)')
    parser.add_argument('--ids', type=int, nargs='+', help='only these object ids (CAD mode)')
    parser.add_argument('--features', choices=('ours', 'paper'), default='ours',
                        help='ours: HOG + metric shape features from depth (default); '
                             "paper: HOG only (the paper's descriptor)")
    parser.add_argument('--steps-deg', type=float, default=DEFAULT_STEP_DEG,
                        help='turntable step in degrees (paper: 1; default '
                             f'{DEFAULT_STEP_DEG:g}, see README)')
    parser.add_argument('--positions', type=int, default=4, help='places on the plate (4)')
    parser.add_argument('--augmentations', type=int, default=DEFAULT_AUGMENTATIONS,
                        help='shear/zoom copies per view (paper: 3, i.e. 4 images per view; '
                             f'default {DEFAULT_AUGMENTATIONS})')
    parser.add_argument('--recipe', choices=RECIPE_CHOICES,
                        default='clutter',
                        help='clutter: views among other parts on random tables, cut as '
                             "loose boxes (default); turntable: the paper's silhouette crops; "
                             "packaged: the packaged model's (turntable + scenes); hybrid: "
                             "clutter + packaged's scenes and learner; hybrid-turntable: hybrid "
                             "+ the turntable views; options given win")
    _add_clutter_arguments(parser)
    parser.add_argument('--scenes', type=int, default=0,
                        help='also train on the crops of this many simulated two-view scenes '
                             '(CAD mode, ours features; 0 = turntable only, the paper)')
    parser.add_argument('--smoothed-share', type=float, metavar='F',
                        help="share (0-1) of the turntable views and --scenes rendered with "
                             "the stereo-like 'smoothed' depth, the rest per-pixel (default: "
                             "the recipe's, else TurntableParams.smoothed_depth_share)")
    parser.add_argument('--seed', type=int, default=0, help='rendering and training seed')
    parser.add_argument('--workers', type=int, default=0, metavar='N',
                        help='render the --scenes in N processes (default 0: the idle cores, at '
                             'most 4; the model is the same for any N)')
    parser.add_argument('--cell', type=int, default=HogParams.cell_px, help='HOG cell px (6)')
    parser.add_argument('--bins', type=int, default=HogParams.bins, help='HOG bins (4)')
    parser.add_argument('--epochs', type=int, default=ClassifierParams.epochs)
    parser.add_argument('--hog-weight', type=float, default=ClassifierParams.hog_weight,
                        help='weight of the standardised HOG beside the shape features '
                             f'(default {ClassifierParams.hog_weight})')
    parser.add_argument('--alpha', type=float, default=ClassifierParams.alpha,
                        help=f"L2 regularisation of 'sgd' (default {ClassifierParams.alpha:g})")
    parser.add_argument('--pa-c', type=float, default=ClassifierParams.pa_c,
                        help=f'aggressiveness C of pa1 / pa2 (default {ClassifierParams.pa_c:g})')
    parser.add_argument('--average', action=argparse.BooleanOptionalAction,
                        default=ClassifierParams.average,
                        help='keep the weights averaged over all updates (averaged SGD)')
    parser.add_argument('--kernel', type=int, default=ClassifierParams.kernel_components,
                        metavar='M', help='learn on an RBF feature map with M landmarks '
                        '(Nyström; 0 = on the descriptors, the paper; default '
                        f'{ClassifierParams.kernel_components})')
    parser.add_argument('--kernel-axes', type=int, default=ClassifierParams.kernel_axes,
                        help='principal axes of the descriptor the map keeps (default '
                             f'{ClassifierParams.kernel_axes})')
    parser.add_argument('--kernel-gamma', type=float, default=ClassifierParams.kernel_gamma,
                        help='RBF width, relative to the descriptor length (default '
                             f'{ClassifierParams.kernel_gamma:g})')
    parser.add_argument('--reject-margin', type=float, default=0.0,
                        help='store this reject threshold in the model (0 = never reject)')


def _add_clutter_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of the cluttered crops (``--recipe clutter`` and the recipes built on it)."""
    parser.add_argument('--turntable-crops', action=argparse.BooleanOptionalAction,
                        default=False,
                        help="with --recipe clutter: also the turntable's own views (the "
                             "packaged recipe's), cut by their boxes as the cluttered crops are")
    parser.add_argument('--copies', type=int, default=ClutterRecipe.copies,
                        help=f'cluttered crops per view (default {ClutterRecipe.copies})')
    parser.add_argument('--clutter-param', action='append', metavar='NAME=VALUE',
                        help='override a ClutterRecipe / ClutterParams field, e.g. '
                             'neighbours=0,0 or photometric=false (repeatable)')
    parser.add_argument('--box-size', action=argparse.BooleanOptionalAction, default=True,
                        help="with --recipe clutter: also learn the box's angular size")


def parse_kinds(text: str) -> list[str]:
    """'all' | 'sgd' | 'sgd,pa1' -> list of learner kinds."""
    kinds = list(KINDS) if text == 'all' else [k.strip() for k in text.split(',') if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise TlessbotError(f'unknown classifier {bad or text!r}; choose from {KINDS} or all')
    return kinds


def output_paths(out: Path, kinds: list[str]) -> dict[str, Path]:
    """One path per learner: ``out`` itself for one, ``<stem>_<kind>.npz`` for several."""
    if len(kinds) == 1:
        return {kinds[0]: out}
    return {kind: out.with_name(f'{out.stem}_{kind}{out.suffix or ".npz"}') for kind in kinds}


def sample_shape(sample, shape: ShapeParams) -> np.ndarray:
    """(F,) float32 shape vector of a turntable sample, NaN where its depth is unusable."""
    values = shape_features(region_points_world(sample.depth_m, sample.mask, sample.K,
                                                sample.T_world_camera), params=shape)
    return np.full(shape.feature_dim, np.nan, np.float32) if values is None else values


def turntable_features(models_dir: Path, hog: HogParams, *, ids: list[int] | None,
                       steps_deg: float, positions: int, augmentations: int,
                       seed: int, shape: ShapeParams | None = None,
                       smoothed_share: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Render the turntable and describe every crop: ((N, D) float32, (N,) int64 ids).

    D is ``hog.feature_dim``, plus ``shape.feature_dim`` shape values (NaN = no usable depth)
    when ``shape`` is given. With ``hog.crop_mode == 'box'`` each view is cut by its
    silhouette's box, background kept (as ``describe_regions`` cuts a box at inference). A share
    ``smoothed_share`` (0-1) of the views has the stereo-like 'smoothed' depth
    (``TurntableParams.smoothed_depth_share``).
    """
    from tqdm import tqdm

    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.turntable import Turntable, TurntableParams

    models = load_models(models_dir, ids)
    if len(models) < 2:
        raise TlessbotError(f'need at least 2 models to train, found {len(models)}')
    params = TurntableParams(positions=positions, step_deg=steps_deg,
                             augmentations=augmentations, smoothed_depth_share=smoothed_share)
    table = Turntable(models, params=params, seed=seed)
    hog_dim = hog.feature_dim
    features = np.empty((len(table), hog_dim + (shape.feature_dim if shape else 0)),
                        np.float32)
    if hog.crop_mode == 'box':
        return _turntable_box_features(table, hog, shape, features)
    labels = np.empty(len(table), np.int64)
    batch = np.empty((256, hog.crop_px, hog.crop_px), np.uint8)
    count = filled = 0
    batch_labels = []
    with tqdm(total=len(table), desc='render+HOG', unit='crop') as bar:
        for sample in table.samples():
            batch[filled] = normalise_crop(sample.rgb, mask=sample.mask, params=hog)
            if shape is not None:
                features[count + filled, hog_dim:] = sample_shape(sample, shape)
            batch_labels.append(sample.obj_id)
            filled += 1
            if filled == len(batch):
                features[count:count + filled, :hog_dim] = hog_features(batch, params=hog)
                labels[count:count + filled] = batch_labels
                count, filled, batch_labels = count + filled, 0, []
            bar.update()
    features[count:count + filled, :hog_dim] = hog_features(batch[:filled], params=hog)
    labels[count:count + filled] = batch_labels
    count += filled
    return features[:count], labels[:count]


def _turntable_box_features(table, hog: HogParams, shape: ShapeParams | None,
                            features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`turntable_features` of box crops: each view described by ``describe_regions``
    (its silhouette's box, and the box's angular size with ``hog.box_size``) into
    ``features`` ((N, D) float32, filled in place); returns it with the (N,) int64 ids."""
    from tqdm import tqdm

    labels = np.empty(len(table), np.int64)
    hog_dim = hog.feature_dim
    count = 0
    for sample in tqdm(table.samples(), total=len(table), desc='render+HOG', unit='crop'):
        features[count, :hog_dim] = describe_regions(
            sample.rgb, masks=[sample.mask], params=hog, focal_px=float(sample.K[0, 0]))[0]
        if shape is not None:
            features[count, hog_dim:] = sample_shape(sample, shape)
        labels[count] = sample.obj_id
        count += 1
    return features[:count], labels[:count]


def read_image_crop(path: Path, hog: HogParams) -> np.ndarray:
    """Normalised crop of one image file; an alpha channel is used as the silhouette."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DatasetError(f'cannot read image {path}')
    if image.ndim == 3 and image.shape[2] == 4:
        mask = image[..., 3] > 127
        rgb = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
        if mask.any():
            return normalise_crop(rgb, mask=mask, params=hog)
        return normalise_crop(rgb, params=hog)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return normalise_crop(image, params=hog)


def image_folder_features(folder: Path, hog: HogParams) -> tuple[np.ndarray, np.ndarray]:
    """Describe every <obj_id>/*.png of a folder: ((N, D) float32, (N,) int64 ids)."""
    from tqdm import tqdm

    if not folder.is_dir():
        raise DatasetError(f'image folder not found: {folder}')
    files = []
    for sub in sorted(folder.iterdir()):
        if sub.is_dir() and sub.name.isdigit() and int(sub.name) > 0:
            files += [(int(sub.name), path) for path in sorted(sub.glob('*.png'))]
    if len({obj_id for obj_id, _ in files}) < 2:
        raise DatasetError(f'{folder} must hold at least two <obj_id>/ folders of .png crops '
                           '(obj_id a positive integer)')
    crops = np.empty((len(files), hog.crop_px, hog.crop_px), np.uint8)
    for i, (_, path) in enumerate(tqdm(files, desc='read+normalise', unit='img')):
        crops[i] = read_image_crop(path, hog)
    return hog_features(crops, params=hog), np.array([obj_id for obj_id, _ in files], np.int64)


def apply_recipe(args: argparse.Namespace) -> argparse.Namespace:
    """``args`` with ``args.recipe``'s value for every option left at its default, and
    ``TurntableParams.smoothed_depth_share`` for ``--smoothed-share`` where neither sets it."""
    from tlessbot_ros.sim.turntable import TurntableParams

    defaults = argparse.ArgumentParser()
    add_arguments(defaults)
    values = {key: value for key, value in RECIPES.get(args.recipe or '', {}).items()
              if key == 'recipe' or getattr(args, key) == defaults.get_default(key)}
    merged = argparse.Namespace(**{**vars(args), **values})
    if merged.smoothed_share is None:   # its default lives in the turntable's parameters
        merged.smoothed_share = TurntableParams.smoothed_depth_share
    return merged


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    args = apply_recipe(args)
    kinds = parse_kinds(args.classifier)
    try:  # settings are checked before minutes of rendering
        cad_clutter = args.models is not None and args.recipe == 'clutter'
        hog = HogParams(cell_px=args.cell, bins=args.bins,
                        crop_mode='box' if cad_clutter else 'mask',
                        box_size=cad_clutter and args.box_size)
        if args.copies < 1:
            raise ValueError('--copies must be >= 1')
        if args.workers < 0:
            raise ValueError('--workers must be >= 0 (0: the idle cores)')
        if not 0.0 <= args.smoothed_share <= 1.0:
            raise ValueError(f'--smoothed-share must be in [0, 1], got {args.smoothed_share}')
        learners = {kind: ClassifierParams(
            kind=kind, epochs=args.epochs, alpha=args.alpha, pa_c=args.pa_c,
            average=args.average,
            reject_margin=args.reject_margin, hog_weight=args.hog_weight,
            kernel_components=args.kernel, kernel_axes=args.kernel_axes,
            kernel_gamma=args.kernel_gamma) for kind in kinds}
    except ValueError as error:
        raise TlessbotError(str(error)) from None
    started = time.perf_counter()
    if args.models is None and args.from_images is None and not args.captures:
        raise TlessbotError('nothing to train on: give --models, --from-images or --captures')
    if args.from_images is not None and args.captures:
        raise TlessbotError('--captures goes with --models, not --from-images')
    shape = ShapeParams() if args.features == 'ours' and (
        args.models is not None or args.captures) else None
    if args.models is None and args.captures:
        features, labels, source = np.empty((0, 0), np.float32), np.empty(0, np.int64), {}
    elif args.models is not None:
        features, labels, source = cad_features(args, hog, shape)
    else:
        if args.features == 'ours':
            print('image folders have no depth: training a paper-features (HOG only) model')
        features, labels = image_folder_features(args.from_images, hog)
        source = {'source': 'images', 'folder': str(args.from_images)}
    if args.captures:
        from tlessbot_ros.tools.support.captures import add_captures

        features, labels = add_captures(args.captures, hog, shape, features, labels, source,
                                        config=args.config, every=args.capture_every,
                                        copies=args.capture_augmentations, seed=args.seed)
    source['features'] = 'ours' if shape is not None else 'paper'
    data_s = time.perf_counter() - started
    ids = np.unique(labels[labels != BACKGROUND_ID])
    if len(ids) < 2:
        raise TlessbotError(f'need crops of at least 2 parts to train, got {ids.tolist()}')
    background = int(np.sum(labels == BACKGROUND_ID))
    print(f'{len(labels)} crops of {len(ids)} objects'
          + (f' ({background} of background)' if background else '') + f' in {data_s:.1f} s')
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for kind, path in output_paths(args.out, kinds).items():
        params = learners[kind]
        t0 = time.perf_counter()
        one_fit = params.kernel_components > 0   # one batch fit: no progress inside it
        with tqdm(total=args.epochs * len(labels), unit='sample', unit_scale=True,
                  desc=f'train {kind}' + (' (one batch fit)' if one_fit else '')) as bar, \
                _elapsed_shown(bar if one_fit else None):
            model = train_classifier(features, labels, hog_params=hog, params=params,
                                     seed=args.seed, on_batch=bar.update,
                                     shape_params=shape)
        train_s = time.perf_counter() - t0
        train_acc = model.info['train_accuracy']
        info = dict(model.info, **source, alpha=params.alpha, pa_c=params.pa_c,
                    average=params.average,
                    kernel_components=params.kernel_components,
                    kernel_axes=params.kernel_axes, kernel_gamma=params.kernel_gamma,
                    data_s=round(data_s, 2), train_s=round(train_s, 2))
        dataclasses.replace(model, hog_params=hog, kind=kind, info=info,
                            shape_params=shape).save(path)
        print(f'{kind}: trained in {train_s:.1f} s (data {data_s:.1f} s), training accuracy '
              f'{100 * train_acc:.1f} % -> {path}')
    return 0


@contextlib.contextmanager
def _elapsed_shown(bar, every_s: float = 1.0) -> Iterator[None]:
    """Redraw ``bar`` every ``every_s`` while the block runs, so its elapsed time moves during
    a step that reports no progress (None: nothing)."""
    done = threading.Event()

    def redraw() -> None:
        while not done.wait(every_s):
            bar.refresh()

    if bar is not None:
        threading.Thread(target=redraw, daemon=True, name='train_progress').start()
    try:
        yield
    finally:
        done.set()


def cad_features(args: argparse.Namespace, hog: HogParams, shape: ShapeParams | None
                 ) -> tuple[np.ndarray, np.ndarray, dict]:
    """(features, labels, source info) of CAD training: the cluttered recipe (default) or
    the paper's turntable, plus the crops of ``--scenes`` simulated scenes."""
    if args.recipe == 'clutter':
        features, labels = clutter_features(
            args.models, hog, ids=args.ids, steps_deg=args.steps_deg, positions=args.positions,
            seed=args.seed,
            recipe=dataclasses.replace(recipe_with(args.clutter_param), copies=args.copies),
            shape_of=None if shape is None else (lambda sample: sample_shape(sample, shape)),
            shape_dim=0 if shape is None else shape.feature_dim,
            smoothed_share=args.smoothed_share)
        source = {'source': 'clutter', 'steps_deg': args.steps_deg,
                  'positions': args.positions, 'copies': args.copies,
                  'smoothed_share': args.smoothed_share}
        if args.turntable_crops:
            more, more_labels = turntable_features(
                args.models, hog, ids=args.ids, steps_deg=args.steps_deg,
                positions=args.positions, augmentations=args.augmentations, seed=args.seed,
                shape=shape, smoothed_share=args.smoothed_share)
            features = np.vstack([features, more])
            labels = np.concatenate([labels, more_labels])
            source.update(turntable_crops=len(more_labels), augmentations=args.augmentations)
    else:
        features, labels = turntable_features(
            args.models, hog, ids=args.ids, steps_deg=args.steps_deg, positions=args.positions,
            augmentations=args.augmentations, seed=args.seed, shape=shape,
            smoothed_share=args.smoothed_share)
        source = {'source': 'turntable', 'steps_deg': args.steps_deg,
                  'positions': args.positions, 'augmentations': args.augmentations,
                  'smoothed_share': args.smoothed_share}
    if args.scenes:
        if shape is None:
            raise TlessbotError('--scenes needs --features ours')
        more, more_labels = scene_features(args.models, hog, shape, ids=args.ids,
                                           scenes=args.scenes,
                                           seed=args.seed + SCENE_SEED_OFFSET,
                                           workers=args.workers,
                                           smoothed_share=args.smoothed_share)
        features = np.vstack([features, more])
        labels = np.concatenate([labels, more_labels])
        source.update(scenes=args.scenes, scene_crops=len(more_labels))
    return features, labels, source
