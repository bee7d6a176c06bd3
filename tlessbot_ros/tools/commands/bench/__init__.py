"""Benchmarks: per-stage timings and comparisons (tlessbot bench <name> --help)."""
from __future__ import annotations

import argparse
import importlib
from pathlib import Path

from tlessbot_ros.tools.support.discovery import discover, first_doc_line

_BENCH_DIR = Path(__file__).resolve().parent


def available_benchmarks() -> dict[str, str]:
    """Benchmark name -> one-line help, from module docstrings (nothing is imported)."""
    return {name: first_doc_line(path) for name, path in discover(_BENCH_DIR).items()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    benchmarks = available_benchmarks()
    subparsers = parser.add_subparsers(dest='benchmark', required=True, metavar='NAME')
    for name, text in benchmarks.items():
        sub = subparsers.add_parser(name, help=text, description=text)
        module = name.replace('-', '_')
        sub.set_defaults(_bench_module=module)
        # Each benchmark adds its own options; import only to build its parser.
        importlib.import_module(f'{__name__}.{module}').add_arguments(sub)


def run(args: argparse.Namespace) -> int:
    module = importlib.import_module(f'{__name__}.{args._bench_module}')
    return int(module.run(args) or 0)
