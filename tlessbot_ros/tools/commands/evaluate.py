"""Score the pipeline (or given poses) on a BOP-format dataset: report.json, report.md, plots.

  tlessbot evaluate --dataset DIR --models DIR [--split NAME] [--classifier FILE]
                    [--templates FILE] [--oracle none|boxes|boxes+classes]
                    [--poses RESULTS.csv] [--limit N] [--out DIR]

With --poses the given BOP results are only scored. Otherwise the perception pipeline
(core.pipeline) runs on every frame; --oracle feeds ground-truth boxes (and classes) instead of
the localiser (and classifier). Without --classifier / --templates both are built from
--models as ``tlessbot parts build`` builds them (same recipe) and kept in the start-up cache
by the models' content: a dataset of new parts is scored in one command. A dataset with
test_top/ and test_side/ is evaluated as two views and scored in the side camera. Parts with
visib_fract >= 0.3 are the targets. The reports name the parts as the graph does: a parts
folder's ``models/`` by its manifest, a CAD folder by its file stems, T-LESS and BOP by obj_NN.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from tlessbot_ros.core.common import SIDE
from tlessbot_ros.core.common.names import part_name
from tlessbot_ros.errors import DatasetError, ModelFileError, TlessbotError
from tlessbot_ros.io.bop_results import read_results, write_results
from tlessbot_ros.io.models import object_id_from_path
from tlessbot_ros.io.parts import PartsFolder, model_names
from tlessbot_ros.tools.support.eval_frames import TWO_VIEW_SPLITS, bag_frames, pipeline_frames
from tlessbot_ros.tools.support.eval_recognition import write_recognition_page
from tlessbot_ros.tools.support.eval_scoring import FrameOutput, load_scoring_models, score_frames
from tlessbot_ros.tools.support.parts_build import BuildOptions, cached_parts
from tlessbot_ros.tools.support.report import cell


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--dataset', type=Path, help='BOP dataset root')
    parser.add_argument('--bag', type=Path,
                        help='instead of --dataset: a bag with /ground_truth topics, replayed '
                             'through the ROS graph (each node its own process)')
    parser.add_argument('--models', required=True, type=Path,
                        help='CAD models: obj_NN.stl folder or BOP models/ with models_info.json')
    parser.add_argument('--split', help='evaluate this single split (default: test_top + '
                        'test_side when both exist, else the only split)')
    parser.add_argument('--classifier', type=Path, help='classifier .npz (tlessbot train; '
                        'default: built from --models as tlessbot parts build does, cached)')
    parser.add_argument('--templates', type=Path, help='template database .npz (tlessbot '
                        'templates; default: built from --models likewise)')
    parser.add_argument('--oracle', choices=('none', 'boxes', 'boxes+classes'), default='none',
                        help='feed ground-truth boxes (and classes) to the pipeline')
    parser.add_argument('--background-boxes', type=int, default=0, metavar='N',
                        help='with --oracle boxes: N random boxes a frame away from the parts; '
                             'each named as a part counts as a false positive')
    parser.add_argument('--poses', type=Path, help='only score these poses (BOP results CSV)')
    parser.add_argument('--limit', type=int, help='score at most N frames')
    parser.add_argument('--out', type=Path, default=Path('eval_out'), help='output folder')
    parser.add_argument('--pose-workers', type=int, default=0, metavar='N',
                        help='fit parts in N worker processes besides this one, as the pose '
                             'node does (config/cell.yaml: 1); the poses are the same')
    parser.add_argument('--pose-param', action='append', metavar='NAME=VALUE',
                        help='override a PoseParams field, e.g. icp_iterations=6 (repeatable)')
    parser.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE',
                        help='override a field of a pipeline stage (LocaliseParams, '
                             'ClassifyParams, FitParams), e.g. verify_accept_fitness=0.9 '
                             '(repeatable)')


def _scored_split(dataset: Path, split: str | None) -> tuple[str, bool]:
    """(split to score, two-view?) after checking the dataset layout."""
    from tlessbot_ros.io.bop import list_splits
    splits = list_splits(dataset)
    if split is not None:
        if split not in splits:
            raise DatasetError(f'{dataset} has no split {split!r} (available: '
                               f'{", ".join(splits)})')
        return split, False
    if all(s in splits for s in TWO_VIEW_SPLITS):
        return f'test_{SIDE}', True
    if len(splits) == 1:
        return splits[0], False
    raise DatasetError(f'{dataset} has several splits ({", ".join(splits)}); choose one with '
                       '--split')


def _scoring_folder(models: Path, built: PartsFolder | None) -> Path:
    """The models to score with: ``models``, or for a CAD folder without obj_NN files (names
    of its own) the ones the parts build converted from it (same ids, its symmetries)."""
    if built is None or any(object_id_from_path(p) is not None for p in models.iterdir()):
        return models
    return built.models


def _given_poses(path: Path) -> dict[tuple[int, int], FrameOutput]:
    outputs: dict[tuple[int, int], FrameOutput] = {}
    for result in read_results(path):
        output = outputs.setdefault((result.scene_id, result.im_id), FrameOutput())
        output.poses.append(result)
        if result.time_s >= 0:
            output.timings_ms['frame'] = 1e3 * result.time_s
    return outputs


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.io.bop import read_split
    from tlessbot_ros.tools.support.report import write_report

    if args.limit is not None and args.limit <= 0:
        raise TlessbotError('--limit must be positive')
    if args.background_boxes < 0 or (args.background_boxes and args.oracle != 'boxes'):
        raise TlessbotError('--background-boxes takes N >= 0 and needs --oracle boxes')
    if not args.models.is_dir():
        raise ModelFileError(f'models folder not found: {args.models}')
    if (args.dataset is None) == (args.bag is None):
        raise TlessbotError('give exactly one of --dataset DIR and --bag FILE')
    started = time.perf_counter()
    frames: list[tuple[object, FrameOutput]] = []
    built: PartsFolder | None = None
    if args.bag is not None:
        frames = bag_frames(args.bag, classifier=args.classifier, templates=args.templates,
                            limit=args.limit)
        from tlessbot_ros.tools.support.eval_frames import bag_cameras
        from tlessbot_ros.tools.support.graph_run import main_camera
        split, two_view = f'bag ({main_camera(list(bag_cameras(args.bag)))} camera)', False
        mode = f'ROS graph on {args.bag.name}'
    elif args.poses is not None:
        split, two_view = _scored_split(args.dataset, args.split)
        given = _given_poses(args.poses)
        images = read_split(args.dataset, split, limit=args.limit, load_masks=False)
        for image in tqdm(images, desc='scoring', unit='frame', total=args.limit):
            frames.append((image, given.get((image.scene_id, image.im_id), FrameOutput())))
        mode = f'given poses ({args.poses.name})'
    else:
        split, two_view = _scored_split(args.dataset, args.split)
        templates, classifier = args.templates, args.classifier
        if templates is None or (classifier is None and args.oracle != 'boxes+classes'):
            # built as tlessbot parts build builds them, once per set of CAD files
            need_classifier = classifier is None and args.oracle != 'boxes+classes'
            built = cached_parts(args.models, BuildOptions(), classifier=need_classifier)
            templates = templates or built.templates
            classifier = built.classifier if need_classifier else classifier
        iterator = pipeline_frames(
            args.dataset, split, two_view, templates=templates, classifier=classifier,
            oracle=args.oracle, limit=args.limit, pose_overrides=args.pose_param,
            pipeline_overrides=args.pipeline_param, pose_workers=args.pose_workers,
            background=args.background_boxes)
        for item in tqdm(iterator, desc='pipeline', unit='frame', total=args.limit):
            frames.append(item)
        mode = f'pipeline, oracle {args.oracle}'
    if not frames:
        raise DatasetError(f'{args.dataset or args.bag}: {split} has no images')
    ids = {gt.obj_id for image, _ in frames for gt in image.gt}
    ids |= {p.obj_id for _, o in frames for p in o.poses}
    models = load_scoring_models(_scoring_folder(args.models, built), ids)
    report = score_frames(frames, models)
    # the parts' own names (a parts folder's manifest, CAD file stems), else obj_NN
    names = model_names(args.models)
    report['names'] = {str(i): part_name(i, names) for i in sorted(ids)}
    args.out.mkdir(parents=True, exist_ok=True)
    recognition = write_recognition_page(frames, args.out, names)
    if recognition is not None:
        report['recognition'].update(recognition)
    report['mode'] = mode
    report['dataset'] = str(args.dataset or args.bag)
    report['split'] = ' + '.join(TWO_VIEW_SPLITS) if two_view else split
    report['run_time_s'] = time.perf_counter() - started
    write_results(args.out / 'estimates.csv', [p for _, o in frames for p in o.poses])
    (args.out / 'report.json').write_text(json.dumps(report, indent=2) + '\n')
    write_report(report, args.out)
    _print_summary(report, recognition, args.out)
    return 0


def _print_summary(report: dict, recognition: dict | None, out: Path) -> None:
    """What evaluate prints: skipped frames, recognition, unknowns, pose recall, times."""
    pose = report['pose']
    skipped = report['skipped']
    if skipped['pose_frames_without_depth']:
        print(f'pose skipped on {skipped["pose_frames_without_depth"]} frames without depth '
              f'({skipped["parts_not_posed"]} parts): pose measures are over the rest')
    if recognition is not None:
        print(_recognition_line(recognition, out / 'recognition.md'))
    if (fp := report['recognition']['false_pos_per_frame']) is not None:
        print(f'unknowns: parts called unknown {_fmt(report["recognition"]["unknown_rate"])}, '
              f'regions that are no part named as one {fp:.2f} a frame (false positives), '
              f'regions called unknown {report["recognition"]["unknown_per_frame"]:.2f} a frame')
    print(f'{report["frames"]} frames, {report["objects_gt"]} parts: '
          f'5cm5deg {_fmt(pose["recall_5cm5deg"])}, VSD<0.3 {_fmt(pose["recall_vsd03"])}, '
          f'ADD-S {_fmt(pose["recall_adds01d"])}, MSSD AR {_fmt(pose["mssd_recall"])} '
          f'-> {out}')
    timing = report['timing_ms']
    if timing.get('pose_per_part') is not None:
        plane = timing.get('table_plane')
        print(f'median ms: pose per part {timing["pose_per_part"]:.1f}, pose per frame '
              f'{timing["pose"]:.1f}' + ('' if plane is None else
                                        f', table plane per frame (all views) {plane:.1f}'))


def _fmt(value: float | None) -> str:
    return 'n/a' if value is None else f'{value:.3f}'


def _recognition_line(recognition: dict, page: Path) -> str:
    """One line of top-1: every crop (classifier alone), the crops with depth (alone, after
    the pose stage)."""
    return (f'recognition on ground-truth boxes: top-1 {cell(recognition["top1_classifier"])} '
            f'(classifier alone); on the {recognition["posed_crops"]} crops with depth '
            f'{cell(recognition["top1_classifier_posed"])} alone, '
            f'{cell(recognition["top1_after_pose"])} after the pose stage -> {page}')

