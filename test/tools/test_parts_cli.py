"""tlessbot parts: unusable CAD folders are refused in one line, and nothing is left behind."""
import numpy as np

from tlessbot_ros.io.parts import write_mesh
from tlessbot_ros.tools.cli import main


def _box(path, size_mm):
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * size_mm
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    write_mesh(path, v, f)


def test_wrong_units_refused_before_any_work(tmp_path, capsys):
    cad, out = tmp_path / 'cad', tmp_path / 'parts'
    cad.mkdir()
    _box(cad / 'block.stl', np.array([0.04, 0.03, 0.02]))     # metres, read as mm
    _box(cad / 'plate.stl', np.array([0.06, 0.04, 0.004]))
    assert main(['parts', 'build', '--models', str(cad), '--out', str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()   # every file named, one line each
    assert err[0] == 'tlessbot parts: error: 2 of 2 CAD files cannot be used:'
    assert [line.split()[0] for line in err[1:]] == ['block.stl', 'plate.stl']
    assert all('probably in m; --units m if all the files are in m' in line for line in err[1:])
    assert not out.exists()


def test_one_part_is_not_a_set_and_names_are_checked(tmp_path, capsys):
    cad = tmp_path / 'cad'
    cad.mkdir()
    _box(cad / 'block.stl', np.array([40.0, 30.0, 20.0]))
    assert main(['parts', 'build', '--models', str(cad), '--out', str(tmp_path / 'p')]) == 1
    assert 'needs at least 2' in capsys.readouterr().err
    _box(cad / '2nd block.stl', np.array([40.0, 30.0, 20.0]))
    assert main(['parts', 'build', '--models', str(cad), '--out', str(tmp_path / 'p')]) == 1
    assert 'rename the file to part_2nd_block.stl' in capsys.readouterr().err
    assert main(['parts', 'generate', '--out', str(tmp_path / 'g'), '--names', 'gear']) == 1
    assert "no generated part ['gear']" in capsys.readouterr().err


def test_an_unknown_recipe_is_refused_before_any_work(tmp_path, capsys):
    import pytest

    cad = tmp_path / 'cad'
    cad.mkdir()
    _box(cad / 'block.stl', np.array([40.0, 30.0, 20.0]))
    _box(cad / 'plate.stl', np.array([60.0, 40.0, 4.0]))
    with pytest.raises(SystemExit) as refused:      # argparse, not `tlessbot train` minutes on
        main(['parts', 'build', '--models', str(cad), '--out', str(tmp_path / 'p'),
              '--recipe', 'fancy'])
    assert refused.value.code == 2
    assert "invalid choice: 'fancy'" in capsys.readouterr().err
    assert not (tmp_path / 'p').exists()


def test_the_cached_classifier_is_keyed_by_what_trains_it_not_the_rig(tmp_path, monkeypatch):
    from pathlib import Path

    from tlessbot_ros.tools.support.parts_build import BuildOptions, classifier_cache_path

    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path))
    base = classifier_cache_path('abc', BuildOptions())
    assert base.parent == tmp_path / 'classifiers'
    assert classifier_cache_path('abc', BuildOptions(config=Path('other_cell.yaml'))) == base
    for other in (classifier_cache_path('abd', BuildOptions()),
                  classifier_cache_path('abc', BuildOptions(seed=1)),
                  classifier_cache_path('abc', BuildOptions(recipe=None)),
                  classifier_cache_path('abc', BuildOptions(train_args=['--scenes=200'])),
                  classifier_cache_path('abc', BuildOptions(smoothed_share=0.5))):
        assert other != base


def test_a_failed_second_process_says_why(tmp_path):
    import pytest

    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.tools.support.parts_build import finish_tool, start_tool

    log = tmp_path / 'templates.log'
    process = start_tool('templates', '--models', str(tmp_path / 'none'), '--out',
                         str(tmp_path / 't.npz'), log=log)
    with pytest.raises(TlessbotError, match='tlessbot templates failed') as error:
        finish_tool('templates', process, log)
    assert 'none' in str(error.value)   # its log's end is quoted: the folder it missed


def test_a_terminated_build_leaves_no_folder_and_no_child(tmp_path):
    """SIGTERM to the tool alone (`timeout`, `kill`) stops a build as Ctrl-C does: the half-
    built folder is removed and the train and templates children end with it (before, the
    folder stayed and `tlessbot train` ran on alone)."""
    import os
    import signal
    import sys
    import time

    import psutil
    from running import Running

    cad, out = tmp_path / 'cad', tmp_path / 'parts'
    cad.mkdir()
    _box(cad / 'block.stl', np.array([40.0, 30.0, 20.0]))
    _box(cad / 'plate.stl', np.array([60.0, 40.0, 4.0]))
    env = {**os.environ, 'TLESSBOT_CACHE_DIR': str(tmp_path / 'cache')}   # nothing cached
    build = Running([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'parts', 'build',
                     '--models', str(cad), '--out', str(out), '--check-frames', '0'], env=env)
    tool = psutil.Process(build.process.pid)
    deadline, children = time.monotonic() + 120, []
    while len(children) < 2 and time.monotonic() < deadline and build.process.poll() is None:
        children = [child for child in tool.children(recursive=True)
                    if {'train', 'templates'} & set(child.cmdline())]
        time.sleep(0.2)
    assert len(children) == 2 and out.is_dir(), build.output
    build.process.send_signal(signal.SIGTERM)
    assert build.wait(60) == 130, build.output
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, [child.cmdline() for child in alive]
    assert not out.exists()


def test_a_parts_folder_classifier_learns_from_cluttered_crops_by_default(monkeypatch, tmp_path):
    """The default build trains on the cluttered box crops that hold on real images, with
    simulated scenes and the kernel learner (``train --recipe hybrid``)."""
    import argparse

    from tlessbot_ros.tools.commands import train
    from tlessbot_ros.tools.support import parts_build

    asked = []
    monkeypatch.setattr(parts_build, 'run_tool', lambda *argv: asked.append(argv))
    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path / 'cache'))
    (tmp_path / 'out').mkdir()
    parts_build._train_classifier(tmp_path / 'out', parts_build.BuildOptions(), 'abc')
    assert asked and asked[0][0] == 'train'
    parser = argparse.ArgumentParser()
    train.add_arguments(parser)
    args = train.apply_recipe(parser.parse_args(list(asked[0][1:])))
    assert (args.recipe, args.scenes, args.kernel, args.classifier, args.average) == \
        ('clutter', 800, 4000, 'perceptron', True)
