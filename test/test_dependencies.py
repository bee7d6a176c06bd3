"""Run-time dependencies are declared where each install path reads them: package.xml (rosdep
keys, the colcon path), setup.py's install_requires and requirements/runtime.txt (pip)."""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUNTIME_SOURCES = [*sorted((REPO / 'tlessbot_ros').rglob('*.py')),
                   *sorted((REPO / 'launch').glob('*.launch.py'))]

# Third-party import name -> (rosdep key, pip distribution). Keys checked against ros/rosdistro
# rosdep/python.yaml; None = rosdep has no key, pip installs it (package.xml says so).
THIRD_PARTY = {
    'numpy': ('python3-numpy', 'numpy'),
    'scipy': ('python3-scipy', 'scipy'),
    'numba': ('python3-numba', 'numba'),
    'cv2': ('python3-opencv', 'opencv-python-headless'),
    'sklearn': ('python3-sklearn', 'scikit-learn'),
    # No key of its own: the python3-sklearn system package depends on python3-threadpoolctl.
    'threadpoolctl': ('python3-sklearn', 'threadpoolctl'),
    'open3d': ('python3-open3d-pip', 'open3d'),
    'yaml': ('python3-yaml', 'pyyaml'),
    'tqdm': ('python3-tqdm', 'tqdm'),
    'matplotlib': ('python3-matplotlib', 'matplotlib'),
    'skimage': ('python3-skimage', 'scikit-image'),
    'rosbags': (None, 'rosbags'),
    'mcap': (None, 'mcap'),
    'zstandard': (None, 'zstandard'),
    # The rosdep key librealsense2 is the C++ SDK; the Python wheel bundles its own.
    'pyrealsense2': (None, 'pyrealsense2'),
    'foxglove': (None, 'foxglove-sdk'),
}
# pip distributions setup.py keeps in an extra rather than install_requires.
OPTIONAL_PIP = {'pyrealsense2': 'realsense', 'foxglove-sdk': 'foxglove'}
MESSAGE_TYPE = re.compile(r"""['"]([a-z][a-z0-9_]*_(?:msgs|interfaces))/msg/[A-Z]\w*['"]""")


def imported_top_levels() -> set[str]:
    """Top-level names of every absolute import in the run-time sources, stdlib excluded."""
    names = set()
    for path in RUNTIME_SOURCES:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split('.')[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != 'tlessbot_ros'}


def message_packages() -> set[str]:
    """ROS interface packages named in 'pkg/msg/Type' strings (loaded by message_class)."""
    return {m for path in RUNTIME_SOURCES for m in MESSAGE_TYPE.findall(path.read_text())}


def package_xml(tag: str) -> set[str]:
    return {e.text.strip() for e in ET.parse(REPO / 'package.xml').getroot().iter(tag)}


def setup_keyword(name: str):
    """The literal value of a keyword argument of setup.py's setup() call."""
    for node in ast.walk(ast.parse((REPO / 'setup.py').read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == 'setup':
            for keyword in node.keywords:
                if keyword.arg == name:
                    return ast.literal_eval(keyword.value)
    raise AssertionError(f'setup.py has no {name}=')


def distribution(requirement: str) -> str:
    return re.match(r'[A-Za-z0-9_.-]+', requirement).group(0).lower()


def test_every_import_is_a_known_dependency():
    ros_packages = package_xml('exec_depend')
    unknown = sorted(imported_top_levels() - set(THIRD_PARTY) - ros_packages)
    assert not unknown, f'imports with no dependency declared: {unknown}; add them to ' \
        'THIRD_PARTY here and to package.xml / setup.py, or as a ROS package to package.xml'


def test_package_xml_declares_exactly_what_is_used():
    imports = imported_top_levels()
    third_party = {THIRD_PARTY[n][0] for n in imports if n in THIRD_PARTY} - {None}
    ros = (imports - set(THIRD_PARTY)) | message_packages()
    used, declared = third_party | ros, package_xml('exec_depend')
    assert declared == used, f'missing: {sorted(used - declared)}, ' \
        f'unused: {sorted(declared - used)}'


def test_pip_requirements_are_exactly_the_third_party_imports():
    used = {THIRD_PARTY[n][1] for n in imported_top_levels() if n in THIRD_PARTY}
    required = {distribution(r) for r in setup_keyword('install_requires')}
    extras = setup_keyword('extras_require')
    optional = {pip for pip, extra in OPTIONAL_PIP.items()
                if pip in map(distribution, extras[extra])}
    assert required | optional == used
    assert not required & set(OPTIONAL_PIP)


def test_runtime_requirements_file_matches_setup_py():
    """requirements/runtime.txt is the pip line of the colcon path (README)."""
    lines = (REPO / 'requirements' / 'runtime.txt').read_text().splitlines()
    listed = [line.split('#')[0].strip() for line in lines if line.split('#')[0].strip()]
    extras = setup_keyword('extras_require')
    expected = setup_keyword('install_requires') + [
        r for extra in set(OPTIONAL_PIP.values()) for r in extras[extra]]
    assert sorted(listed) == sorted(expected)


def test_the_scan_sees_the_imports_it_must():
    """The import scan itself: lazy imports inside functions count (numba, pyrealsense2)."""
    imports = imported_top_levels()
    assert {'numba', 'pyrealsense2', 'rclpy', 'launch_ros', 'threadpoolctl'} <= imports
    assert {'diagnostic_msgs', 'sensor_msgs', 'geometry_msgs'} <= message_packages()
