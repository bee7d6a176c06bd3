"""tlessbot capture --simulate writes labelled capture bags; train --captures reads them."""
import numpy as np
import pytest

from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import bag_topics
from tlessbot_ros.io.capture import CaptureLabel, part_id, read_capture_label
from tlessbot_ros.tools.cli import main


@pytest.fixture(scope='module')
def capture_bags(tless_models_dir, tmp_path_factory):
    """Simulated capture bags of parts 5 and 19: 3 frames each, both cameras."""
    root = tmp_path_factory.mktemp('captures')
    bags = []
    for name, extra in (('obj_05', []), ('obj_19', ['--with-background'])):
        bag = root / name
        assert main(['capture', '--simulate', '--models', str(tless_models_dir), '--part', name,
                     '--out', str(bag), '--frames', '3', '--step-deg', '120',
                     '--positions', '1', *extra]) == 0
        bags.append(bag)
    return bags


def test_a_simulated_capture_bag_holds_the_cameras_and_its_label(capture_bags):
    bag = capture_bags[0]
    topics = bag_topics(bag)
    for camera in ('top', 'side'):
        for kind in ('color/image_raw', 'color/camera_info',
                     'aligned_depth_to_color/image_raw', 'aligned_depth_to_color/camera_info'):
            assert topics[f'/{camera}/{kind}'].startswith('sensor_msgs/msg/')
    assert not any(t.startswith('/ground_truth') for t in topics)
    label = read_capture_label(bag)
    assert (label.part, label.obj_id, label.cameras) == ('obj_05', 5, ['top', 'side'])
    angles = list(label.turntable_deg().values())
    assert len(angles) == 3 and len(set(angles)) == 3 and all(0 <= a < 360 for a in angles)


def test_the_localiser_cuts_the_part_out_of_every_frame(capture_bags):
    """With the session's empty table (obj_19) and without (obj_05)."""
    from tlessbot_ros.tools.support.captures import _backgrounds, capture_crops

    assert read_capture_label(capture_bags[1]).background == 'background'
    assert set(_backgrounds(capture_bags[1], ['top', 'side'])) == {'top', 'side'}
    assert _backgrounds(capture_bags[0], ['top', 'side']) == {}
    skipped = []
    crops = list(capture_crops(capture_bags[1], skipped=skipped))
    crops += list(capture_crops(capture_bags[0], skipped=skipped))
    assert not skipped and len(crops) == 12
    for crop in crops[:6]:
        assert crop.obj_id == 19 and crop.T_world_camera is not None
        x, y, w, h = crop.box
        assert crop.mask.sum() >= 100 and crop.mask[y:y + h, x:x + w].sum() == crop.mask.sum()
        # the part stands in the middle of the work area, where the cameras look
        height, width = crop.mask.shape
        assert abs(x + w / 2 - width / 2) < width / 4 and abs(y + h / 2 - height / 2) < height / 4


def test_train_from_captures_alone_and_mixed_with_cad(capture_bags, tless_models_dir,
                                                      tmp_path, capsys):
    alone = tmp_path / 'captures.npz'
    assert main(['train', '--captures', *map(str, capture_bags), '--out', str(alone)]) == 0
    model = LinearClassifier.load(alone)
    assert model.class_ids.tolist() == [5, 19] and model.shape_params is not None
    assert model.info['source'] == 'captures' and model.info['capture_crops'] == 12
    assert model.info['samples'] == 12

    mixed = tmp_path / 'mixed.npz'
    assert main(['train', '--models', str(tless_models_dir), '--ids', '5', '19', '21',
                 '--recipe', 'turntable',
                 '--steps-deg', '120', '--positions', '1', '--augmentations', '0',
                 '--captures', *map(str, capture_bags), '--out', str(mixed)]) == 0
    model = LinearClassifier.load(mixed)
    assert model.class_ids.tolist() == [5, 19, 21] and model.info['capture_crops'] == 12
    assert model.info['samples'] > 12 and model.info['source'] == 'turntable'


def test_user_errors_are_one_line(capture_bags, tmp_path, capsys):
    assert main(['train', '--captures', str(capture_bags[0]), '--out',
                 str(tmp_path / 'm.npz')]) == 1
    assert 'at least 2 parts' in capsys.readouterr().err
    assert main(['train', '--captures', str(tmp_path), '--out', str(tmp_path / 'm.npz')]) == 1
    assert 'not a capture bag' in capsys.readouterr().err
    assert main(['capture', '--part', 'obj_05', '--out', str(capture_bags[0])]) == 1
    assert 'exists' in capsys.readouterr().err
    assert main(['capture', '--part', 'bracket', '--out', str(tmp_path / 'b')]) == 1
    assert '--obj-id' in capsys.readouterr().err


def test_the_label_round_trips(tmp_path):
    label = CaptureLabel('bracket', 31, ['side'], frames=[
        {'stamp_ns': 5, 'turntable_deg': 12.5}, {'stamp_ns': 9, 'turntable_deg': None}])
    label.write(tmp_path)
    again = read_capture_label(tmp_path)
    assert (again.part, again.obj_id, again.cameras) == ('bracket', 31, ['side'])
    assert again.turntable_deg() == {5: 12.5} and len(again.frames) == 2
    assert part_id('obj_07') == 7
    with pytest.raises(BagError, match='positive'):
        CaptureLabel('x', 0, ['side'])
    (tmp_path / 'capture.yaml').write_text('part: [unclosed', encoding='utf-8')
    with pytest.raises(BagError, match='not a capture label'):
        read_capture_label(tmp_path)


@pytest.mark.ros
@pytest.mark.rosbag
def test_capture_records_any_publisher_of_the_camera_topics(capture_bags, tmp_path):
    import sys

    from running import Running

    from tlessbot_ros.tools.support.captures import capture_crops

    cli = [sys.executable, '-m', 'tlessbot_ros.tools.cli']
    out = tmp_path / 'live'
    capture = Running([*cli, 'capture', '--part', 'obj_19', '--cameras', 'side', '--frames', '4',
                       '--turntable-deg-per-s', '30', '--out', str(out),
                       '--discovery-timeout', '20'])
    replay = Running([*cli, 'replay', str(capture_bags[1]), '--loop', '--restamp'])
    try:
        assert capture.wait(90) == 0, capture.output
    finally:
        replay.interrupt(20)
    label = read_capture_label(out)
    assert (label.part, label.obj_id, label.cameras) == ('obj_19', 19, ['side'])
    assert len(label.frames) >= 4
    stamps = [f['stamp_ns'] for f in label.frames]
    angles = [f['turntable_deg'] for f in label.frames]
    assert angles[0] == 0 and all(b > a for a, b in zip(stamps, stamps[1:]))
    assert angles[1] == pytest.approx(30 * (stamps[1] - stamps[0]) * 1e-9, abs=1e-3)
    assert set(bag_topics(out)) == {'/side/color/image_raw', '/side/color/camera_info',
                                    '/side/aligned_depth_to_color/image_raw',
                                    '/side/aligned_depth_to_color/camera_info'}
    crops = list(capture_crops(out))
    assert len(crops) == len(label.frames) >= 4   # every labelled frame is whole
    assert all(c.obj_id == 19 and c.camera == 'side' for c in crops)


def test_augmented_copies_of_capture_crops(capture_bags):
    from tlessbot_ros.core.recognise import HogParams, ShapeParams
    from tlessbot_ros.tools.support.captures import capture_features

    plain, ids, _ = capture_features(capture_bags[:1], HogParams(), ShapeParams(),
                                     progress=False)
    more, more_ids, counts = capture_features(capture_bags[:1], HogParams(), ShapeParams(),
                                              copies=2, seed=4, progress=False)
    assert len(plain) == 6 and len(more) == counts['capture_crops'] == 18
    assert set(more_ids.tolist()) == {5}
    np.testing.assert_array_equal(more[0], plain[0])          # each crop, then its copies
    assert not np.allclose(more[1], more[0], equal_nan=True)
    assert np.isfinite(more[:, HogParams().feature_dim:]).mean() > 0.9   # their depth warped too
