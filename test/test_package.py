"""Packaging invariants: layering, rclpy-free core, lint."""
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_core_and_conversions_import_without_rclpy(tmp_path):
    # A meta-path hook makes every ROS import fail, as in an environment without rclpy.
    code = (
        'import sys\n'
        'class Block:\n'
        '    def find_spec(self, name, path=None, target=None):\n'
        "        if name.split('.')[0] in ('rclpy', 'sensor_msgs', 'geometry_msgs', 'std_msgs'):\n"
        "            raise ImportError('blocked: ' + name)\n"
        'sys.meta_path.insert(0, Block())\n'
        'import tlessbot_ros.core, tlessbot_ros.conversions, tlessbot_ros.core.common.geometry\n'
        "print('ok')\n"
    )
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == 'ok'


def test_core_never_imports_ros_or_upper_layers():
    forbidden = ('rclpy', 'tlessbot_ros.nodes', 'tlessbot_ros.tools', 'tlessbot_ros.conversions',
                 'tlessbot_ros.sim', 'tlessbot_ros.sensors', 'tlessbot_ros.parallel',
                 'sensor_msgs', 'geometry_msgs')
    assert not _imports_of(REPO / 'tlessbot_ros' / 'core', forbidden)


STAGES = ('localise', 'recognise', 'pose')


def test_each_stage_imports_only_itself_and_common():
    core = REPO / 'tlessbot_ros' / 'core'
    for stage in STAGES:
        others = tuple(f'tlessbot_ros.core.{s}' for s in STAGES if s != stage) + (
            'tlessbot_ros.core.pipeline', 'tlessbot_ros.core.metrics')
        assert not _imports_of(core / stage, others), stage
    assert not _imports_of(core / 'common', tuple(f'tlessbot_ros.core.{s}' for s in STAGES) + (
        'tlessbot_ros.core.pipeline', 'tlessbot_ros.core.metrics'))


def test_stage_packages_export_an_explicit_api():
    import importlib

    for package in ('common',) + STAGES:
        module = importlib.import_module(f'tlessbot_ros.core.{package}')
        assert module.__all__, package
        for name in module.__all__:
            assert getattr(module, name) is not None, f'{package}.{name}'


def test_a_light_module_does_not_load_open3d(tmp_path):
    code = ('import sys\n'
            'import tlessbot_ros.core.common.geometry, tlessbot_ros.conversions\n'
            "print('open3d' in sys.modules)\n")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == 'False'


def test_pose_workers_never_import_ros_or_upper_layers():
    forbidden = ('rclpy', 'tlessbot_ros.nodes', 'tlessbot_ros.tools', 'tlessbot_ros.conversions',
                 'sensor_msgs', 'geometry_msgs')
    assert not _imports_of(REPO / 'tlessbot_ros' / 'parallel', forbidden)


def _imports_of(folder: Path, forbidden: tuple[str, ...]) -> list[str]:
    """Import lines under ``folder`` that name one of ``forbidden``."""
    offenders = []
    for path in folder.rglob('*.py'):
        for line in path.read_text().splitlines():
            stripped = line.strip()
            if stripped.startswith(('import ', 'from ')) and any(
                    f' {name}' in stripped for name in forbidden):
                offenders.append(f'{path.name}: {stripped}')
    return offenders


def test_ruff_is_clean():
    ruff = shutil.which('ruff', path=str(Path(sys.executable).parent)) or shutil.which('ruff')
    assert ruff, 'ruff is part of the test tools (requirements/dev.txt)'
    result = subprocess.run([ruff, 'check', 'tlessbot_ros', 'test', 'launch'], cwd=REPO,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_cli_lists_commands():
    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', '--help'],
                            capture_output=True, text=True)
    assert result.returncode == 0
    assert 'usage: tlessbot <command>' in result.stdout
