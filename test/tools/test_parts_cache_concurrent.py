"""The parts cache of `tlessbot evaluate --models CAD` when two runs build it at once: each
builds aside and moves a finished folder in, so neither finds the other's half-built one."""
import shutil

from tlessbot_ros.io import parts as parts_io
from tlessbot_ros.io.cache import cache_dir
from tlessbot_ros.tools.support import parts_build
from tlessbot_ros.tools.support.parts_build import BuildOptions, cached_parts, parts_cache_name


def _cad(tless_models_dir, tmp_path):
    cad = tmp_path / 'cad'
    cad.mkdir()
    for obj_id in (5, 11):
        shutil.copy(tless_models_dir / f'obj_{obj_id:02d}.stl', cad)
    return cad


def test_a_half_built_cache_folder_does_not_stop_the_build(tless_models_dir, tmp_path,
                                                            monkeypatch):
    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path / 'cache'))
    cad = _cad(tless_models_dir, tmp_path)
    out = cache_dir() / 'parts' / parts_cache_name(cad, BuildOptions())
    (out / 'models').mkdir(parents=True)   # what a build still running (or killed) leaves
    folder = cached_parts(cad, BuildOptions(), classifier=False)
    assert folder.templates.is_file() and (out / parts_io.MANIFEST).is_file()
    assert [p.name for p in out.parent.iterdir()] == [out.name]   # nothing left aside


def test_a_cache_another_run_finished_first_is_kept(tless_models_dir, tmp_path, monkeypatch):
    monkeypatch.setenv('TLESSBOT_CACHE_DIR', str(tmp_path / 'cache'))
    cad = _cad(tless_models_dir, tmp_path)
    out = cache_dir() / 'parts' / parts_cache_name(cad, BuildOptions())

    def build_while_another_finishes(cad, building, options, **kwargs):
        for folder, text in ((out, 'theirs'), (building, 'ours')):
            folder.mkdir(parents=True)
            for name in (parts_io.MANIFEST, 'templates.npz'):
                (folder / name).write_text(text)
    monkeypatch.setattr(parts_build, 'build_parts', build_while_another_finishes)
    cached_parts(cad, BuildOptions(), classifier=False)
    assert (out / parts_io.MANIFEST).read_text() == 'theirs'
    assert [p.name for p in out.parent.iterdir()] == [out.name]
