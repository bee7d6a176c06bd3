"""Types are part of the tests (house style 11): strict mypy on core/ and conversions/ as
setup.cfg's [mypy] section configures it, and the bugs it found."""
from __future__ import annotations

import ast
import configparser
import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / 'tlessbot_ros'


def test_mypy_strict_is_clean(monkeypatch):
    api = pytest.importorskip('mypy.api', reason='mypy is not installed (requirements/dev.txt)')
    monkeypatch.chdir(REPO)   # setup.cfg's [mypy] names the files, relative to the clone
    stdout, stderr, status = api.run(['--config-file', 'setup.cfg'])
    assert status == 0, f'mypy (setup.cfg [mypy]) found:\n{stdout}{stderr}'
    assert 'Success: no issues found' in stdout


def test_mypy_checks_core_and_conversions_strictly():
    config = configparser.ConfigParser()
    config.read(REPO / 'setup.cfg')
    mypy = config['mypy']
    assert mypy.getboolean('strict')
    assert {f.strip() for f in mypy['files'].split(',')} == {
        'tlessbot_ros/core', 'tlessbot_ros/conversions'}
    # only third-party packages without type information may be skipped
    skipped = [name for name in config.sections() if name.startswith('mypy-')
               and config[name].getboolean('ignore_missing_imports', fallback=False)]
    assert all('tlessbot_ros' not in name for name in skipped)
    assert not mypy.getboolean('ignore_missing_imports', fallback=False)


def _lazy_packages() -> list[str]:
    found = []
    for init in sorted((PACKAGE / 'core').rglob('__init__.py')) + \
            sorted((PACKAGE / 'conversions').rglob('__init__.py')):
        if 'lazy_api(' in init.read_text():
            found.append('.'.join(init.parent.relative_to(REPO).parts))
    return found


def _type_checking_names(init: Path) -> set[str]:
    """The names an ``__init__.py`` imports under ``if TYPE_CHECKING:``."""
    names = set()
    for node in ast.parse(init.read_text()).body:
        if isinstance(node, ast.If) and 'TYPE_CHECKING' in ast.unparse(node.test):
            for inner in ast.walk(node):
                if isinstance(inner, ast.ImportFrom):
                    names |= {alias.asname or alias.name for alias in inner.names}
    return names


def test_lazy_packages_show_mypy_their_whole_api():
    """A lazy package's ``__getattr__`` makes every name mypy does not see typed ``Any``:
    the names imported for type checking must be exactly its public ones, and mypy must
    treat them as re-exported (setup.cfg)."""
    packages = _lazy_packages()
    assert 'tlessbot_ros.core.common' in packages and 'tlessbot_ros.core.pose' in packages
    for name in packages:
        module = importlib.import_module(name)
        init = REPO.joinpath(*name.split('.'), '__init__.py')
        assert _type_checking_names(init) == set(module._HOME), name
        assert sorted(module.__all__) == sorted(module._HOME), name
    config = configparser.ConfigParser()
    config.read(REPO / 'setup.cfg')
    reexported = set()
    for section in config.sections():
        if config[section].getboolean('implicit_reexport', fallback=False):
            reexported |= {m.strip() for m in section.removeprefix('mypy-').split(',')}
    assert reexported == set(packages)


# ------------------------------------------------------------------ bugs that mypy found


def test_fitting_a_part_without_templates_is_a_clear_error():
    """PerceptionPipeline.fit_part (the pose workers call it) passed ``pose_estimator=None``
    on to the fit, which failed deep inside with an AttributeError."""
    from tlessbot_ros.core.frame import Detection, PartJob
    from tlessbot_ros.core.pipeline import PerceptionPipeline

    job = PartJob(Detection(1, 21, 'side', (0, 0, 4, 4)), np.zeros((10, 3)), (21,), None)
    with pytest.raises(ValueError, match='no template database loaded'):
        PerceptionPipeline().fit_part(job)


def test_package_share_of_a_namespace_package_is_a_clear_error(tmp_path, monkeypatch):
    """A package without ``__init__.py`` has no ``__file__``: package_share raised a
    TypeError from ``Path(None)``."""
    from tlessbot_ros.conversions.schemas import package_share

    (tmp_path / 'tlessbot_no_such_msgs' / 'msg').mkdir(parents=True)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, 'tlessbot_no_such_msgs', raising=False)
    with pytest.raises(ValueError, match="'tlessbot_no_such_msgs' has no share folder"):
        package_share('tlessbot_no_such_msgs')
