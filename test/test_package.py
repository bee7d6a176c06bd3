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
# core modules above the stages: the pipeline that composes them and what it is made of
ABOVE_STAGES = tuple(f'tlessbot_ros.core.{name}' for name in (
    'pipeline', 'metrics', 'frame', 'label_views', 'part_fit', 'fragments', 'calibrate'))


def test_each_stage_imports_only_itself_and_common():
    core = REPO / 'tlessbot_ros' / 'core'
    for stage in STAGES:
        others = tuple(f'tlessbot_ros.core.{s}' for s in STAGES if s != stage) + ABOVE_STAGES
        assert not _imports_of(core / stage, others), stage
    assert not _imports_of(core / 'common',
                           tuple(f'tlessbot_ros.core.{s}' for s in STAGES) + ABOVE_STAGES)


def test_calibration_sits_on_top_of_core():
    """core/calibrate uses the pipeline; nothing else in core uses it."""
    core = REPO / 'tlessbot_ros' / 'core'
    for path in core.glob('*.py'):
        assert not _imports_of_file(path, ('tlessbot_ros.core.calibrate',)), path.name
    for package in ('common',) + STAGES:
        assert not _imports_of(core / package, ('tlessbot_ros.core.calibrate',)), package


def test_stage_packages_export_an_explicit_api():
    import importlib

    for package in ('common', 'calibrate') + STAGES:
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
    return [offender for path in folder.rglob('*.py')
            for offender in _imports_of_file(path, forbidden)]


def _imports_of_file(path: Path, forbidden: tuple[str, ...]) -> list[str]:
    """Import lines of ``path`` that name one of ``forbidden``."""
    offenders = []
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


# ------------------------------------------------------------------------ rooms that stay small
PACKAGE = REPO / 'tlessbot_ros'
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def _package_sources() -> dict[str, Path]:
    """Module name -> file, for every module of the package."""
    modules = {}
    for path in PACKAGE.rglob('*.py'):
        parts = list(path.relative_to(REPO).with_suffix('').parts)
        if parts[-1] == '__init__':
            parts = parts[:-1]
        modules['.'.join(parts)] = path
    return modules


def long_functions(limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """'path:line name (N lines)' of every function longer than ``limit`` lines (its def line
    to its last line, decorators not counted)."""
    import ast

    found = []
    for path in sorted(PACKAGE.rglob('*.py')):
        relative = path.relative_to(PACKAGE).as_posix()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > limit:
                    found.append(f'{relative}:{node.lineno} {node.name} ({length} lines)')
    return found


def _runtime_imports(path: Path, module: str) -> list[tuple[str, tuple[str, ...]]]:
    """(imported module, names) of every import in ``path`` (module ``module``), those under
    ``if TYPE_CHECKING:`` left out (they never run)."""
    import ast

    tree = ast.parse(path.read_text())
    typing_only = {id(inner) for node in ast.walk(tree)
                   if isinstance(node, ast.If) and 'TYPE_CHECKING' in ast.unparse(node.test)
                   for inner in ast.walk(node)}
    package = module.split('.') if path.name == '__init__.py' else module.split('.')[:-1]
    imports = []
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            imports.extend((alias.name, ()) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                base = '.'.join(package[:len(package) - node.level + 1] + ([base] if base else []))
            imports.append((base, tuple(alias.name for alias in node.names)))
    return imports


def test_no_module_is_over_500_lines():
    long = {path.relative_to(PACKAGE).as_posix(): n for path in PACKAGE.rglob('*.py')
            if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f'split these by responsibility: {long}'


def test_no_function_is_over_80_lines():
    assert not long_functions(), 'shorten these functions: ' + '; '.join(long_functions())


def test_the_function_cap_notices_a_long_function(tmp_path, monkeypatch):
    package = tmp_path / 'tlessbot_ros'
    (package / 'tools' / 'commands' / 'bench').mkdir(parents=True)
    body = ''.join(f'    x{k} = {k}\n' for k in range(85))
    (package / 'long.py').write_text(f'def long():\n{body}')
    (package / 'tools' / 'commands' / 'bench' / 'bench.py').write_text(f'def bench():\n{body}')
    (package / 'short.py').write_text('def short():\n    return 1\n')
    monkeypatch.setattr(sys.modules[__name__], 'PACKAGE', package)
    assert long_functions() == ['long.py:1 long (86 lines)',
                                'tools/commands/bench/bench.py:1 bench (86 lines)']


def test_no_module_imports_another_modules_private_names():
    offenders = []
    for module, path in _package_sources().items():
        for source, names in _runtime_imports(path, module):
            private = [name for name in names if name.startswith('_') and name != '__version__']
            if source.startswith('tlessbot_ros') and private:
                offenders.append(f'{module}: from {source} import {", ".join(private)}')
    assert not offenders, 'make these public or move them: ' + '; '.join(offenders)


def _import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports at run time (function-level imports too)."""
    modules = _package_sources()
    graph = {}
    for module, path in modules.items():
        edges = set()
        for source, names in _runtime_imports(path, module):
            for name in names or ('',):
                target = f'{source}.{name}' if name else source
                edges.add(target if target in modules else source)
        graph[module] = {edge for edge in edges if edge in modules and edge != module}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_no_import_cycle():
    assert not _cycles(_import_graph())


def test_the_cycle_finder_finds_a_cycle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}, 'e': set()}
    assert _cycles(graph) == [['a', 'b', 'c']]


# ------------------------------------------------------------------------ benches, their own tier
def _bench_modules_after(argv: list[str]) -> list[str]:
    """The bench modules ``tlessbot <argv>`` imported (run in a fresh interpreter)."""
    code = '\n'.join((
        'import contextlib, sys',
        'from tlessbot_ros.tools.cli import main',
        'with contextlib.suppress(SystemExit):',
        f'    main({argv!r})',
        "bench = [m for m in sys.modules if m.startswith('tlessbot_ros.tools.commands.bench.')]",
        "print('imported:', *sorted(bench))"))
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=REPO)
    assert result.returncode == 0, result.stderr
    return result.stdout.strip().splitlines()[-1].split()[1:]


def test_bench_help_imports_no_bench_module():
    assert _bench_modules_after(['bench', '--help']) == []


def test_a_bench_imports_only_itself():
    assert _bench_modules_after(['bench', 'transport', '--help']) == [
        'tlessbot_ros.tools.commands.bench.transport']


def test_bench_help_lists_every_bench():
    from tlessbot_ros.tools.commands.bench import benchmark_table

    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', '--help'],
                            capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    table = benchmark_table()
    assert {'graph', 'nodes', 'transport'} <= set(table)
    for name, bench in table.items():
        assert f'  {name} ' in result.stdout and bench.description in result.stdout
        assert (REPO / (bench.module.replace('.', '/') + '.py')).is_file(), bench.module
