"""Benchmarks: per-stage timings and comparisons (tlessbot bench <name> --help).

The benchmarks are a tier of their own, loaded on demand as ros2cli loads its verbs: a table
names each one's module and its one-line description (read from the module's docstring without
importing it), and only the benchmark that runs is imported, with its options. ``tlessbot bench
--help`` imports none of them.
"""
from __future__ import annotations

import argparse
import importlib
from dataclasses import dataclass
from pathlib import Path

from tlessbot_ros.tools.support.discovery import discover, first_doc_line

_BENCH_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Benchmark:
    """One row of the table: the module that runs it and its one-line description."""

    module: str
    description: str


def benchmark_table() -> dict[str, Benchmark]:
    """Benchmark name -> its module and description (nothing is imported)."""
    return {name: Benchmark(f'{__name__}.{name.replace("-", "_")}', first_doc_line(path))
            for name, path in discover(_BENCH_DIR).items()}


def available_benchmarks() -> dict[str, str]:
    """Benchmark name -> one-line help (nothing is imported)."""
    return {name: bench.description for name, bench in benchmark_table().items()}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    table = benchmark_table()
    width = max((len(name) for name in table), default=0)
    parser.epilog = 'benchmarks:\n' + '\n'.join(
        f'  {name:<{width}}  {bench.description}' for name, bench in table.items())
    parser.add_argument('benchmark', metavar='NAME', choices=list(table),
                        help='the benchmark to run (listed below)')
    parser.add_argument('options', nargs=argparse.REMAINDER,
                        help="the benchmark's options ('tlessbot bench NAME --help')")


def run(args: argparse.Namespace) -> int:
    """Import the chosen benchmark alone, parse its options and run it."""
    bench = benchmark_table()[args.benchmark]
    module = importlib.import_module(bench.module)
    parser = argparse.ArgumentParser(prog=f'tlessbot bench {args.benchmark}',
                                     description=bench.description)
    module.add_arguments(parser)
    options = parser.parse_args(args.options)
    options.benchmark = args.benchmark
    return int(module.run(options) or 0)
