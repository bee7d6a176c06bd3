"""Benchmarks: per-stage timings and comparisons (tlessbot bench <name> --help)."""
from __future__ import annotations

import argparse
import ast
import importlib
from pathlib import Path

_BENCH_DIR = Path(__file__).resolve().parent / 'benchmarks'


def available_benchmarks() -> dict[str, str]:
    """Benchmark name -> one-line help, from module docstrings (nothing is imported)."""
    found = {}
    for path in sorted(_BENCH_DIR.glob('*.py')):
        if path.stem.startswith('_'):
            continue
        doc = ast.get_docstring(ast.parse(path.read_text(encoding='utf-8'))) or ''
        found[path.stem.replace('_', '-')] = doc.strip().splitlines()[0] if doc.strip() else ''
    return found


def add_arguments(parser: argparse.ArgumentParser) -> None:
    benchmarks = available_benchmarks()
    subparsers = parser.add_subparsers(dest='benchmark', required=True, metavar='NAME')
    for name, text in benchmarks.items():
        sub = subparsers.add_parser(name, help=text, description=text)
        module = name.replace('-', '_')
        sub.set_defaults(_bench_module=module)
        # Each benchmark adds its own options; import only to build its parser.
        importlib.import_module(f'tlessbot_ros.tools.benchmarks.{module}').add_arguments(sub)


def run(args: argparse.Namespace) -> int:
    module = importlib.import_module(f'tlessbot_ros.tools.benchmarks.{args._bench_module}')
    return int(module.run(args) or 0)
