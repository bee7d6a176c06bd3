"""The shared support layer of the `tlessbot` commands."""
from types import SimpleNamespace

import numpy as np

from tlessbot_ros.tools.cli import available_commands
from tlessbot_ros.tools.commands.bench import available_benchmarks
from tlessbot_ros.tools.support.models_info import model_geometry_mm, packaged_symmetries


def test_commands_and_benchmarks_are_found_in_their_folders():
    commands = available_commands()
    assert {'bench', 'demo', 'evaluate', 'models-info', 'replay'} <= set(commands)
    assert all(text for text in commands.values())        # each has a help line
    assert {'graph', 'pose', 'template-sweep'} <= set(available_benchmarks())


def test_model_geometry_is_in_millimetres():
    vertices = np.array([[-0.01, 0.0, 0.0], [0.02, 0.03, 0.004]])
    model = SimpleNamespace(vertices=vertices, extent_m=vertices.max(0) - vertices.min(0),
                            diameter_m=0.05)
    geometry = model_geometry_mm(model)
    assert geometry['diameter'] == 50.0
    assert np.allclose([geometry['min_x'], geometry['size_y'], geometry['size_z']],
                       [-10.0, 30.0, 4.0])


def test_packaged_symmetries_cover_the_shipped_models():
    symmetries = packaged_symmetries()
    assert symmetries and all(isinstance(k, int) and 1 <= k <= 30 for k in symmetries)


def test_pipeline_overrides_reach_the_segmentation_and_the_fusion():
    from tlessbot_ros.tools.support.overrides import stage_overrides

    stages = stage_overrides(['depth_split_jump=0', 'keep_depth_splits=false',
                              'verify_accept_fitness=0.9'])
    assert stages['segmentation'].depth_split_jump == 0.0
    assert stages['fusion'].keep_depth_splits is False
    assert stages['fit_params'].verify_accept_fitness == 0.9
