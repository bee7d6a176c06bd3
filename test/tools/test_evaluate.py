"""tlessbot evaluate: scoring given poses on a tiny simulated BOP set, the whole pipeline on
one camera, and its error lines."""
from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from tlessbot_ros.core.common import CameraIntrinsics, make_transform, rotation_about_axis
from tlessbot_ros.io.bop import BopGroundTruth, BopImage, read_split
from tlessbot_ros.io.bop_results import BopEstimate, write_results
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.eval_scoring import with_visible_masks

IDS = (5, 11)


@pytest.fixture(scope='module')
def dataset(tless_models_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp('eval')
    models = root / 'models'
    models.mkdir()
    for obj_id in IDS:
        shutil.copy(tless_models_dir / f'obj_{obj_id:02d}.stl', models)
    data = root / 'bop'
    assert main(['simulate', '--models', str(models), '--out', str(data), '--frames', '3',
                 '--ids', *map(str, IDS), '--parts-min', '2', '--parts-max', '2',
                 '--width', '320', '--height', '240', '--no-progress', '--seed', '3']) == 0
    return models, data


def _estimates(data):
    """Frame 0: every part exact; frame 1: every part 30° off; frame 2: obj_05 shifted 3 cm."""
    results, expected = [], {'targets': 0, 'ok': 0, 'ok_1cm': 0}
    for image in read_split(data, 'test_side', load_masks=False):
        for gt in image.gt:
            counted = gt.visib_fract >= 0.3
            T = gt.T_camera_object.copy()
            ok = ok_1cm = True
            if image.im_id == 1:
                T = T @ make_transform(rotation_about_axis(np.array([1.0, 0, 0]), np.radians(30)),
                                       np.zeros(3))
                ok = ok_1cm = False
            elif image.im_id == 2 and gt.obj_id == 5:
                T[:3, 3] += [0.03, 0.0, 0.0]
                ok_1cm = False
            results.append(BopEstimate(image.scene_id, image.im_id, gt.obj_id, 1.0, T, 0.05))
            expected['targets'] += counted
            expected['ok'] += counted and ok
            expected['ok_1cm'] += counted and ok_1cm
    return results, expected


def _small_models(models, tmp_path):
    """A classifier and templates of ``models`` quick to make: (classifier, templates)."""
    classifier, templates = tmp_path / 'c.npz', tmp_path / 't.npz'
    assert main(['train', '--models', str(models), '--steps-deg', '90', '--positions', '1',
                 '--out', str(classifier)]) == 0
    assert main(['templates', '--models', str(models), '--out', str(templates),
                 '--views', '4']) == 0
    return classifier, templates


def test_scores_given_poses_exactly(dataset, tmp_path):
    models, data = dataset
    results, expected = _estimates(data)
    assert expected['targets'] > 0
    poses = tmp_path / 'poses.csv'
    write_results(poses, results)
    out = tmp_path / 'out'
    assert main(['evaluate', '--dataset', str(data), '--models', str(models),
                 '--poses', str(poses), '--out', str(out)]) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['frames'] == 3
    assert report['objects_gt'] == expected['targets']
    pose = report['pose']
    assert pose['recall_5cm5deg'] == pytest.approx(expected['ok'] / expected['targets'])
    assert pose['recall_1cm5deg'] == pytest.approx(expected['ok_1cm'] / expected['targets'])
    exact = expected['ok_1cm'] / expected['targets']  # these pass every measure
    assert pose['recall_adds01d'] >= exact - 1e-9
    assert pose['recall_vsd03'] >= exact - 1e-9
    assert exact - 1e-9 <= pose['mssd_recall'] < 1
    for key in ('iou07_rate', 'false_pos_per_frame'):
        assert report['detection'][key] is None  # the localiser did not run
    assert report['recognition']['top1'] is None
    assert report['timing_ms']['frame'] == pytest.approx(50.0)
    assert report['timing_ms']['pose'] is None
    assert set(report['per_object']) <= {'5', '11'}
    assert sum(v['objects_gt'] for v in report['per_object'].values()) == expected['targets']
    assert (out / 'report.md').read_text().count('obj_') >= 1
    assert (out / 'recall_per_object.png').stat().st_size > 0
    assert len((out / 'estimates.csv').read_text().splitlines()) == len(results) + 1


def test_reports_name_the_parts_of_a_parts_folder(dataset, tmp_path):
    """--models PARTS/models: report.md and report.json name the parts by PARTS/manifest.json,
    as the graph's topics do."""
    models, data = dataset
    parts = tmp_path / 'parts'
    shutil.copytree(models, parts / 'models')
    (parts / 'manifest.json').write_text(json.dumps(
        {'parts': [{'id': 5, 'name': 'bracket_l'}, {'id': 11, 'name': 'housing'}]}))
    results, _ = _estimates(data)
    poses = tmp_path / 'poses.csv'
    write_results(poses, results)
    out = tmp_path / 'out'
    assert main(['evaluate', '--dataset', str(data), '--models', str(parts / 'models'),
                 '--poses', str(poses), '--out', str(out)]) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['names'] == {k: {'5': 'bracket_l', '11': 'housing'}[k]
                               for k in report['per_object']}
    page = (out / 'report.md').read_text()
    assert all(f'| {name} | ' in page for name in report['names'].values())
    assert 'obj_' not in page


def test_missing_estimates_count_as_misses(dataset, tmp_path):
    models, data = dataset
    poses = tmp_path / 'empty.csv'
    write_results(poses, [])
    out = tmp_path / 'out'
    assert main(['evaluate', '--dataset', str(data), '--models', str(models),
                 '--poses', str(poses), '--out', str(out), '--limit', '1']) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['frames'] == 1
    assert report['pose']['recall_5cm5deg'] == 0.0
    assert report['pose']['mssd_recall'] == 0.0


def test_error_lines(dataset, tmp_path, capsys):
    models, data = dataset
    poses = tmp_path / 'p.csv'
    write_results(poses, [])
    base = ['evaluate', '--models', str(models), '--poses', str(poses), '--out',
            str(tmp_path / 'o')]
    assert main(base + ['--dataset', str(tmp_path)]) == 1
    assert 'not a BOP dataset' in capsys.readouterr().err
    assert main(base + ['--dataset', str(data), '--split', 'test_front']) == 1
    assert "no split 'test_front'" in capsys.readouterr().err
    empty_models = tmp_path / 'models'
    empty_models.mkdir()
    (empty_models / 'obj_05.stl').write_bytes((models / 'obj_05.stl').read_bytes())
    assert main(['evaluate', '--models', str(empty_models), '--poses', str(poses), '--out',
                 str(tmp_path / 'o'), '--dataset', str(data)]) == 1
    assert 'no model' in capsys.readouterr().err
    assert main(['evaluate', '--models', str(models), '--dataset', str(data), '--bag',
                 str(tmp_path / 'b')]) == 1
    assert 'exactly one of --dataset' in capsys.readouterr().err


def test_missing_templates_are_built_once_and_cached(dataset, tmp_path, capsys, monkeypatch):
    models, data = dataset
    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path / 'cache'))
    out = tmp_path / 'o'
    argv = ['evaluate', '--models', str(models), '--dataset', str(data), '--oracle',
            'boxes+classes', '--limit', '1', '--out', str(out)]
    assert main(argv) == 0
    assert 'building the templates of' in capsys.readouterr().out
    built = list((tmp_path / 'cache' / 'parts').glob('*/templates.npz'))
    assert len(built) == 1 and (out / 'report.json').is_file()
    manifest = json.loads((built[0].parent / 'manifest.json').read_text())
    assert [p['name'] for p in manifest['parts']] == ['obj_05', 'obj_11']
    assert main(argv) == 0
    assert 'using the parts built before' in capsys.readouterr().out


def test_a_cad_folder_of_named_parts_is_scored_and_named(tless_models_dir, tmp_path,
                                                         monkeypatch):
    """--models of CAD files named by the user (ids 1, 2 in the order of the names, as parts
    build gives them): scored with the models the build converted, reports carry the names."""
    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path / 'cache'))
    numbered, cad = tmp_path / 'numbered', tmp_path / 'cad'
    numbered.mkdir()
    cad.mkdir()
    for obj_id, (tless, name) in enumerate(((5, 'bracket_l'), (11, 'housing')), start=1):
        shutil.copy(tless_models_dir / f'obj_{tless:02d}.stl', numbered / f'obj_{obj_id:02d}.stl')
        shutil.copy(tless_models_dir / f'obj_{tless:02d}.stl', cad / f'{name}.stl')
    data = tmp_path / 'bop'
    assert main(['simulate', '--models', str(numbered), '--out', str(data), '--frames', '1',
                 '--parts-min', '2', '--parts-max', '2', '--width', '320', '--height', '240',
                 '--no-progress', '--seed', '3']) == 0
    out = tmp_path / 'o'
    assert main(['evaluate', '--models', str(cad), '--dataset', str(data), '--oracle',
                 'boxes+classes', '--out', str(out)]) == 0
    report = json.loads((out / 'report.json').read_text())
    assert report['names'] == {'1': 'bracket_l', '2': 'housing'}
    assert set(report['per_object']) == {'1', '2'}
    page = (out / 'report.md').read_text()
    assert '| bracket_l | ' in page and '| housing | ' in page and 'obj_0' not in page


def test_pose_workers_give_the_same_estimates(dataset, tmp_path):
    models, data = dataset
    common = ['evaluate', '--models', str(models), '--dataset', str(data), '--oracle',
              'boxes+classes', '--templates', str(tmp_path / 'templates.npz')]
    assert main(['templates', '--models', str(models), '--out', str(tmp_path / 'templates.npz'),
                 '--views', '4']) == 0
    assert main([*common, '--out', str(tmp_path / 'alone')]) == 0
    assert main([*common, '--pose-workers', '1', '--out', str(tmp_path / 'workers')]) == 0

    def estimates(name):
        lines = (tmp_path / name / 'estimates.csv').read_text().splitlines()
        return [line.rsplit(',', 1)[0] for line in lines]   # all but the time column
    assert len(estimates('alone')) > 3 and estimates('workers') == estimates('alone')


def test_one_view_without_extrinsics(dataset, tmp_path, capsys):
    from tlessbot_ros.io.bop import copy_with_extrinsics

    models, data = dataset
    bare = tmp_path / 'bare'
    copy_with_extrinsics(data, bare, lambda T: None)
    templates = tmp_path / 'templates.npz'
    assert main(['templates', '--models', str(models), '--out', str(templates),
                 '--views', '4']) == 0
    common = ['evaluate', '--models', str(models), '--oracle', 'boxes+classes',
              '--templates', str(templates)]
    capsys.readouterr()
    assert main([*common, '--dataset', str(bare), '--split', 'test_side', '--out',
                 str(tmp_path / 'o')]) == 0
    out = capsys.readouterr().out
    assert 'table plane per frame' in out and 'pose per part' in out
    report = json.loads((tmp_path / 'o' / 'report.json').read_text())
    assert report['pose']['recall_5cm5deg'] > 0.5
    assert report['timing_ms']['table_plane'] is not None
    assert 'pose, per part fitted' in (tmp_path / 'o' / 'report.md').read_text()
    # two views need the extrinsics: the top view's poses are scored in the side camera
    assert main([*common, '--dataset', str(bare), '--out', str(tmp_path / 'p')]) == 1
    assert 'cam_R_w2c' in capsys.readouterr().err


def test_frames_without_depth_are_classified_and_their_pose_skipped(dataset, tmp_path, capsys):
    models, data = dataset
    some = tmp_path / 'some_depth'
    shutil.copytree(data, some)
    for path in sorted((some / 'test_side').glob('*/depth/*.png'))[1:]:
        path.unlink()  # depth on the first frame only, as on a real RGB set with one RGB-D
    classifier, templates = _small_models(models, tmp_path)
    capsys.readouterr()
    out = tmp_path / 'o'
    assert main(['evaluate', '--models', str(models), '--dataset', str(some), '--split',
                 'test_side', '--oracle', 'boxes', '--classifier', str(classifier),
                 '--templates', str(templates), '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert 'pose skipped on 2 frames without depth' in printed
    report = json.loads((out / 'report.json').read_text())
    assert report['skipped']['pose_frames_without_depth'] == 2
    recognition = report['recognition']
    assert recognition['crops'] == report['objects_gt'] > report['skipped']['parts_not_posed']
    assert 0.0 <= recognition['top1_classifier'] <= 1.0
    assert sum(map(sum, recognition['confusion'])) == recognition['crops']
    page = (out / 'recognition.md').read_text()
    assert '## Confusion' in page and 'obj_05' in page
    if recognition['top1_classifier'] < 1.0:
        assert (out / 'worst_crops.png').is_file()


def test_near_rotations_in_a_results_file_are_accepted(dataset, tmp_path):
    models, data = dataset
    results, expected = _estimates(data)
    for r in results:   # BOP ground-truth files hold determinants up to 1.014
        r.T_camera_object = r.T_camera_object.copy()
        r.T_camera_object[:3, :3] *= 1.004
    write_results(tmp_path / 'near.csv', results)
    assert main(['evaluate', '--dataset', str(data), '--models', str(models), '--poses',
                 str(tmp_path / 'near.csv'), '--out', str(tmp_path / 'o')]) == 0
    report = json.loads((tmp_path / 'o' / 'report.json').read_text())
    assert report['pose']['recall_5cm5deg'] == pytest.approx(expected['ok'] / expected['targets'])


def test_recognition_after_the_pose_stage_counts_only_frames_with_depth():
    from tlessbot_ros.tools.support.eval_recognition import CropAnswer, markdown, summary

    answers = [CropAnswer(0, 0, truth=2, classifier=2, margin=1.0, final=3, posed=True),
               CropAnswer(1, 0, truth=2, classifier=2, margin=1.0, final=2, posed=False),
               CropAnswer(1, 1, truth=4, classifier=2, margin=0.5, final=2, posed=False)]
    result = summary(answers)
    assert result['top1_classifier'] == 2 / 3
    assert (result['posed_crops'], result['top1_classifier_posed'],
            result['top1_after_pose']) == (1, 1.0, 0.0)
    assert result['per_part']['4']['top1_after_pose'] is None   # never posed: not a zero
    assert '| obj_04 | 1 | 0.000 | 0 | n/a |' in markdown(result)
    named = markdown(result, {2: 'bracket_l', 4: 'plate'})   # as a parts folder names them
    assert '| plate | 1 | 0.000 | 0 | n/a |' in named
    assert '| part | unknown | bracket_l | plate |' in named
    assert 'obj_0' not in named
    empty = summary([])
    assert empty['top1_after_pose'] is None and 'n/a' in markdown(empty)


def test_regions_that_are_no_part_named_as_one_are_false_positives():
    from tlessbot_ros.tools.support.eval_scoring import FrameOutput, score_frames

    empty = SimpleNamespace(gt=[], depth_m=None)   # a frame without any of the parts
    localiser = FrameOutput(boxes=[(0, 0, 10, 10, 3), (20, 20, 10, 10, 0),
                                   (40, 40, 10, 10, 7)], classified=True)
    boxes = FrameOutput(classes_by_gt={}, background_named=[0, 4, 0, 0])
    report = score_frames([(empty, localiser), (empty, boxes)], {})
    recognition = report['recognition']
    assert recognition['false_pos_per_frame'] == pytest.approx((2 + 1) / 2)
    assert recognition['unknown_per_frame'] == pytest.approx((1 + 3) / 2)
    assert recognition['unknown_rate'] is None   # no part to name
    given = score_frames([(empty, FrameOutput())], {})['recognition']
    assert given['false_pos_per_frame'] is None and given['unknown_per_frame'] is None


def test_background_boxes_are_named_or_called_unknown(dataset, tmp_path, capsys):
    models, data = dataset
    classifier, templates = _small_models(models, tmp_path)
    common = ['evaluate', '--models', str(models), '--dataset', str(data), '--split',
              'test_side', '--classifier', str(classifier), '--templates', str(templates)]
    capsys.readouterr()
    out = tmp_path / 'o'
    assert main([*common, '--oracle', 'boxes', '--background-boxes', '3',
                 '--out', str(out)]) == 0
    assert 'regions that are no part named as one' in capsys.readouterr().out
    recognition = json.loads((out / 'report.json').read_text())['recognition']
    fp, unknown = recognition['false_pos_per_frame'], recognition['unknown_per_frame']
    assert 0 <= fp <= 3 and fp + unknown >= 3   # every background box is one or the other
    assert 0 <= recognition['unknown_rate'] <= 1
    assert 'regions called unknown per frame' in (out / 'report.md').read_text()
    assert main([*common, '--oracle', 'none', '--background-boxes', '3',
                 '--out', str(tmp_path / 'p')]) == 1
    assert '--background-boxes' in capsys.readouterr().err


def test_a_right_pose_is_scored_against_its_own_part_in_a_pile():
    """Two parts of one class 8 mm apart, turned 90° to each other: the estimate that is
    right for the first lies nearer the second's centre; it is still scored as the first's."""
    from tlessbot_ros.core.common import Symmetries
    from tlessbot_ros.tools.support.eval_scoring import match_poses

    first = make_transform(np.eye(3), [0.0, 0.0, 0.5])
    second = make_transform(rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.pi / 2),
                            [0.008, 0.0, 0.5])
    image = SimpleNamespace(gt=[SimpleNamespace(obj_id=4, T_camera_object=first),
                                SimpleNamespace(obj_id=4, T_camera_object=second)])
    right_for_first = first.copy()
    right_for_first[0, 3] += 0.006            # 6 mm off: 2 mm from the second's centre
    estimates = [BopEstimate(1, 0, 4, 0.9, right_for_first), BopEstimate(1, 0, 4, 0.5, second)]
    models = {4: SimpleNamespace(symmetries=Symmetries())}
    matches = match_poses(image, estimates, models)
    assert matches[0] is estimates[0] and matches[1] is estimates[1]


def test_the_whole_pipeline_on_one_camera_skips_the_pose_of_frames_without_depth(
        dataset, tmp_path, capsys):
    """One split, depth on frame 0 only, no mask_visib/: the shape of a real RGB-D set."""
    models, data = dataset
    one = tmp_path / 'one_camera'
    shutil.copytree(data / 'test_side', one / 'test')
    for path in sorted(one.glob('test/*/depth/*.png'))[1:]:
        path.unlink()
    for folder in one.glob('test/*/mask_visib'):
        shutil.rmtree(folder)
    classifier, templates = _small_models(models, tmp_path)
    capsys.readouterr()
    out = tmp_path / 'o'
    assert main(['evaluate', '--models', str(models), '--dataset', str(one), '--oracle',
                 'none', '--classifier', str(classifier), '--templates', str(templates),
                 '--out', str(out)]) == 0
    assert 'pose skipped on 2 frames without depth' in capsys.readouterr().out
    report = json.loads((out / 'report.json').read_text())
    assert report['skipped']['pose_frames_without_depth'] == 2
    # every target the localiser missed has a cause, from masks ray-cast at the truth
    missed = round(report['objects_gt'] * (1 - report['detection']['iou07_rate']))
    assert sum(report['detection']['breakdown']['missed'].values()) == missed


def test_visible_masks_are_ray_cast_where_the_set_has_none():
    half = 0.02   # a square of 4 cm in the object's z = 0 plane
    square = (np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]]),
              np.array([[0, 1, 2], [0, 2, 3]]))
    models = {1: SimpleNamespace(vertices=square[0], faces=square[1])}
    near, far = make_transform(np.eye(3), [0.0, 0, 0.4]), make_transform(np.eye(3),
                                                                         [0.02, 0, 0.5])
    intrinsics = CameraIntrinsics(100, 100, np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]]))
    image = BopImage('test', 1, 0, None, None, intrinsics, None,
                     [BopGroundTruth(1, T, None, None) for T in (near, far)])
    masked = with_visible_masks(image, models)
    front, back = (gt.mask for gt in masked.gt)
    assert front.sum() > 0 and back.sum() > 0 and not np.any(front & back)
    # the far square, 2 cm aside, shows only beyond the near one's edge
    assert back.sum() < 0.6 * (2 * half * 100 / 0.5) ** 2
    assert image.gt[0].mask is None                             # the input is left as it was
    assert with_visible_masks(masked, models) is masked         # masks present: unchanged
