import numpy as np
import pytest

from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.sim.turntable import Turntable, TurntableParams, write_samples
from tlessbot_ros.tools.cli import main


def test_train_from_cad(tless_models_dir, tmp_path, capsys):
    out = tmp_path / 'model.npz'
    argv = ['train', '--models', str(tless_models_dir), '--ids', '5', '19', '21',
            '--recipe', 'turntable',
            '--steps-deg', '60', '--positions', '2', '--augmentations', '1', '--seed', '3',
            '--out', str(out)]
    assert main(argv) == 0
    assert 'trained in' in capsys.readouterr().out
    model = LinearClassifier.load(out)
    assert model.class_ids.tolist() == [5, 19, 21] and model.kind == 'sgd'
    assert model.info['source'] == 'turntable' and model.info['train_accuracy'] > 0.8
    again = tmp_path / 'again.npz'
    assert main(argv[:-1] + [str(again)]) == 0
    np.testing.assert_array_equal(LinearClassifier.load(again).weights, model.weights)


def test_train_from_cad_in_clutter_by_default(tless_models_dir, tmp_path):
    from tlessbot_ros.core.recognise import BACKGROUND_ID
    from tlessbot_ros.tools.support.train_clutter import ClutterRecipe

    out = tmp_path / 'clutter.npz'
    argv = ['train', '--models', str(tless_models_dir), '--ids', '5', '19', '21',
            '--steps-deg', '90', '--positions', '1', '--seed', '2',
            '--clutter-param', 'background_share=0.5', '--out', str(out)]
    assert main(argv) == 0
    model = LinearClassifier.load(out)
    copies = ClutterRecipe.copies
    assert model.info['source'] == 'clutter' and model.info['copies'] == copies
    assert model.class_ids.tolist() == [BACKGROUND_ID, 5, 19, 21]
    assert model.hog_params.crop_mode == 'box' and model.hog_params.box_size
    assert model.uses_depth and model.info['samples'] == 3 * 4 * copies
    again = tmp_path / 'again.npz'
    assert main(argv[:-1] + [str(again)]) == 0
    np.testing.assert_array_equal(LinearClassifier.load(again).weights, model.weights)
    paper = tmp_path / 'paper.npz'
    assert main(argv[:-4] + ['--out', str(paper), '--features', 'paper', '--no-box-size',
                             '--clutter-param', 'photometric=false']) == 0
    plain = LinearClassifier.load(paper)
    assert plain.class_ids.tolist() == [5, 19, 21] and not plain.hog_params.box_size
    assert not plain.uses_depth


def test_turntable_crops_join_the_cluttered_ones_as_box_crops(tless_models_dir, tmp_path):
    """--turntable-crops adds the turntable's own views to the cluttered crops, described as
    the model describes a region at inference (its box, background kept, and the box's size),
    so one box-crop model learns from both."""
    from tlessbot_ros.core.recognise import HogParams, describe_regions
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.turntable import Turntable, TurntableParams
    from tlessbot_ros.tools.commands.train import turntable_features

    hog = HogParams(crop_mode='box', box_size=True)
    features, labels = turntable_features(tless_models_dir, hog, ids=[5, 19], steps_deg=180,
                                          positions=1, augmentations=0, seed=4)
    assert features.shape == (len(labels), hog.feature_dim) and np.isfinite(features).all()
    table = Turntable(load_models(tless_models_dir, [5, 19]), params=TurntableParams(
        positions=1, step_deg=180, augmentations=0), seed=4)
    first = next(iter(table.samples()))
    expected = describe_regions(first.rgb, masks=[first.mask], params=hog,
                                focal_px=float(first.K[0, 0]))[0]
    np.testing.assert_allclose(features[0], expected, rtol=1e-6)
    assert labels[0] == first.obj_id
    out = tmp_path / 'both.npz'
    argv = ['train', '--models', str(tless_models_dir), '--ids', '5', '19', '--steps-deg',
            '180', '--positions', '1', '--augmentations', '0', '--copies', '1', '--seed', '4',
            '--out', str(out)]
    assert main([*argv, '--turntable-crops']) == 0
    model = LinearClassifier.load(out)
    assert model.hog_params.crop_mode == 'box' and model.hog_params.box_size
    assert model.info['turntable_crops'] == 4 and model.info['samples'] == 4 + 4


def test_clutter_recipe_reads_shape_from_smoothed_depth_for_its_share(tless_models_dir):
    """--smoothed-share reaches the clutter recipe's turntable: the shape part of the features
    changes for the smoothed views, and a share of 0 gives the per-pixel recipe's features."""
    from tlessbot_ros.core.recognise import HogParams, ShapeParams
    from tlessbot_ros.tools.commands.train import sample_shape
    from tlessbot_ros.tools.support.train_clutter import ClutterRecipe, clutter_features

    shape = ShapeParams()
    hog = HogParams(crop_mode='box', box_size=True)
    recipe = ClutterRecipe(copies=1, shape_drop=0.0)

    def features(**share):
        return clutter_features(tless_models_dir, hog, ids=[5, 19], steps_deg=120, positions=1,
                                seed=4, recipe=recipe, shape_dim=shape.feature_dim,
                                shape_of=lambda sample: sample_shape(sample, shape), **share)

    plain, labels = features()
    zero, _ = features(smoothed_share=0.0)
    smoothed, smoothed_labels = features(smoothed_share=1.0)
    np.testing.assert_array_equal(zero, plain)
    np.testing.assert_array_equal(smoothed_labels, labels)
    shape_columns = slice(hog.feature_dim, None)
    changed = ~np.isclose(smoothed[:, shape_columns], plain[:, shape_columns], equal_nan=True)
    assert changed.any(axis=1).all()   # every view's shape vector reads the other depth


def test_train_several_learners_from_images(tless_models_dir, tmp_path):
    from tlessbot_ros.io.models import load_models

    models = load_models(tless_models_dir, [5, 19])
    table = Turntable(models, params=TurntableParams(step_deg=45, positions=1,
                                                     augmentations=1))
    write_samples(table.samples(), tmp_path / 'crops')
    out = tmp_path / 'm.npz'
    assert main(['train', '--from-images', str(tmp_path / 'crops'), '--classifier', 'pa1,pa2',
                 '--cell', '10', '--bins', '3', '--out', str(out)]) == 0
    for kind in ('pa1', 'pa2'):
        model = LinearClassifier.load(tmp_path / f'm_{kind}.npz')
        assert model.kind == kind and model.hog_params.cell_px == 10
        assert model.info['samples'] == 32


@pytest.mark.parametrize('extra, message', [
    (['--classifier', 'svm'], 'unknown classifier'),
    (['--cell', '7'], 'multiple of cell_px'),
    (['--alpha', '0'], 'alpha'),
    (['--copies', '0'], 'copies'),
    (['--smoothed-share', '1.5'], 'smoothed-share'),
])
def test_user_errors(tmp_path, capsys, extra, message):
    (tmp_path / 'imgs').mkdir()
    assert main(['train', '--from-images', str(tmp_path / 'imgs'), '--out',
                 str(tmp_path / 'm.npz')] + extra) == 1
    assert message in capsys.readouterr().err


def test_empty_image_folder(tmp_path, capsys):
    assert main(['train', '--from-images', str(tmp_path), '--out', str(tmp_path / 'm.npz')]) == 1
    assert 'at least two' in capsys.readouterr().err


def test_train_adds_simulated_scene_crops(tless_models_dir, tmp_path):
    from tlessbot_ros.tools.commands.train import SCENE_SEED_OFFSET
    from tlessbot_ros.tools.support.scene_crops import scene_features

    out = tmp_path / 'scenes.npz'
    argv = ['train', '--models', str(tless_models_dir), '--ids', '5', '19', '21',
            '--steps-deg', '90', '--positions', '1', '--scenes', '3', '--hog-weight', '0.3',
            '--average', '--alpha', '1e-5', '--out', str(out)]
    assert main(argv) == 0
    model = LinearClassifier.load(out)
    assert model.info['scenes'] == 3 and model.info['scene_crops'] > 0
    assert model.info['average'] is True and model.info['alpha'] == 1e-5
    assert model.info['samples'] > model.info['scene_crops']   # turntable crops too
    from tlessbot_ros.core.recognise import ShapeParams
    features, labels = scene_features(tless_models_dir, model.hog_params, ShapeParams(),
                                      ids=[5, 19, 21], scenes=3, seed=SCENE_SEED_OFFSET)
    assert len(labels) == model.info['scene_crops'] and set(labels) <= {5, 19, 21}
    assert features.shape[1] == model.feature_dim
    assert np.isfinite(features[:, :model.hog_params.feature_dim]).all()


def test_train_kernel_model_from_images_is_reproducible(tless_models_dir, tmp_path):
    from tlessbot_ros.io.models import load_models

    models = load_models(tless_models_dir, [5, 19, 21])
    table = Turntable(models, params=TurntableParams(step_deg=45, positions=1,
                                                     augmentations=1))
    write_samples(table.samples(), tmp_path / 'crops')
    argv = ['train', '--from-images', str(tmp_path / 'crops'), '--classifier', 'perceptron',
            '--average', '--kernel', '30', '--kernel-axes', '16', '--kernel-gamma', '2']
    assert main(argv + ['--out', str(tmp_path / 'a.npz')]) == 0
    assert main(argv + ['--out', str(tmp_path / 'b.npz')]) == 0
    a, b = LinearClassifier.load(tmp_path / 'a.npz'), LinearClassifier.load(tmp_path / 'b.npz')
    assert a.feature_map is not None and a.feature_map.output_dim == 30
    assert a.weights.shape == (30, 3) and a.info['kernel_components'] == 30
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.feature_map.landmarks, b.feature_map.landmarks)
    assert a.info['train_accuracy'] > 0.8


def test_kernel_settings_are_checked_before_rendering(tmp_path, capsys):
    (tmp_path / 'imgs').mkdir()
    assert main(['train', '--from-images', str(tmp_path / 'imgs'), '--kernel', '-1',
                 '--out', str(tmp_path / 'm.npz')]) == 1
    assert 'kernel_components' in capsys.readouterr().err


@pytest.mark.parametrize('recipe, given, expected', [
    # packaged: the turntable's silhouettes; hybrid: the cluttered crops, with the same
    # scenes and learner
    ('packaged', ['--epochs', '3'], (800, 4000, 256, 0.3, 'perceptron', True, 3, 'turntable')),
    ('hybrid', ['--scenes', '200'], (200, 4000, 256, 0.3, 'perceptron', True, 20, 'clutter')),
    ('hybrid-turntable', [], (800, 4000, 256, 0.3, 'perceptron', True, 20, 'clutter')),
])
def test_named_recipes_set_their_options_and_given_options_win(recipe, given, expected):
    import argparse

    from tlessbot_ros.tools.commands import train

    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    args = train.apply_recipe(parser.parse_args(
        ['--models', 'm', '--out', 'c.npz', '--recipe', recipe, *given]))
    assert (args.scenes, args.kernel, args.kernel_axes, args.hog_weight, args.classifier,
            args.average, args.epochs, args.recipe) == expected
    plain = train.apply_recipe(parser.parse_args(['--models', 'm', '--out', 'c.npz']))
    assert (plain.scenes, plain.classifier, plain.recipe) == \
        (0, parser.get_default('classifier'), 'clutter')


def test_smoothed_share_defaults_to_the_turntables_and_a_given_one_wins():
    import argparse

    from tlessbot_ros.sim.turntable import TurntableParams
    from tlessbot_ros.tools.commands import train

    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    for recipe in ('packaged', 'clutter'):
        args = train.apply_recipe(parser.parse_args(
            ['--models', 'm', '--out', 'c.npz', '--recipe', recipe]))
        assert args.smoothed_share == TurntableParams.smoothed_depth_share
    given = train.apply_recipe(parser.parse_args(
        ['--models', 'm', '--out', 'c.npz', '--recipe', 'packaged', '--smoothed-share', '0.5']))
    assert given.smoothed_share == 0.5
