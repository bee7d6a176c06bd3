"""Docstrings give shapes, units, references and reasons; measurements live in docs/bench/.

House style: a docstring that says "0.13 ms, against 0.9 ms pixel by pixel" records one day's
bench on one host, and stays there after the code or the host has changed. The figure belongs
in a dated report (docs/bench/code-figures.md keeps those moved out); the docstring keeps the
reason in words and points there. This check looks for the shapes such figures take: timings
compared or approximated, speed ratios, and sessions named."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'tlessbot_ros'
TIMING = r'\d+(\.\d+)?\s*(ms|µs)\b'
MEASUREMENT = re.compile('|'.join((
    rf'{TIMING}[^.;]*\b(against|instead of)\b',        # 8 ms instead of 37 ms
    rf'\b(against|instead of)\s+(~|about\s+)?{TIMING}',  # ..., against 0.9 ms
    rf'(~|\babout\s+){TIMING}',                        # ~0.2 ms per call, about 10 ms
    r'\d+(\.\d+)?\s*(x|×)\s+(faster|slower|the time)\b',  # 4x faster, 0.6x the time
    r'\b(four|ten|\d+) times as (long|fast)\b',
    r'\b\w+(th|nd|rd|st) session\b',                   # history
    r'\d+(\.\d+)?\s*%[^.;]*\bagainst\s+\d',            # 94.5 % of all crops against 92.4
)))


def measurements_in_docstrings(source: str) -> list[str]:
    """The docstring lines of ``source`` (a module's text) that read like a bench figure."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            text = ast.get_docstring(node) or ''
            # a figure may run over a line break: test each sentence's text as one line
            found += [line for line in re.split(r'(?<=[.;])\s', ' '.join(text.split()))
                      if MEASUREMENT.search(line)]
    return found


@pytest.mark.parametrize('text', [
    'test (a 640x480 frame of parts: 0.13 ms, against 0.9 ms pixel by pixel).',
    'run after the voxel grid: 8 ms instead of 37 ms on 2 cores.',
    "Computed by OpenCV's 8-bit conversion (4x faster than float input here).",
    'A KD-tree answers in ~0.2 ms per call.',
    'so that one 640x480 view takes about 10 ms.',
    'one per pose at the end (about 0.6x the time of rotating every row).',
    'the check: 94.5-95.3 % of all crops against 92.4-93.7 % for the classifier alone.',
    'the numpy way took four times as long on a 640x480 frame.',
    'as the ninth session found.',
])
def test_a_bench_figure_is_found(text):
    assert measurements_in_docstrings(f'"""{text}"""')


@pytest.mark.parametrize('text', [
    'stamps going forward by more than this, or back by more than 1 ms, reset the tracks.',
    'Correct if below 0.1 × diameter.',
    'Singular values under 5 % of the largest are cut.',
    'Print it at 100 % ("actual size").',
    "frames that come no faster than the graph's average stage works.",
    'each as arrival times at the monitor (p50 / p95 ms).',
    "the paper's protocol (30 objects × 4 × 360 × 4 = 172,800 crops).",
    'Corners farther than ``outlier_px`` (or 3x the median) are dropped.',
    '(e.g. 1 against 3, 4 against 7)',
])
def test_a_definition_is_not_a_figure(text):
    assert not measurements_in_docstrings(f'"""{text}"""')


def test_no_docstring_carries_a_bench_figure():
    found = [f'{path.relative_to(PACKAGE.parent)}: {line}'
             for path in sorted(PACKAGE.rglob('*.py'))
             for line in measurements_in_docstrings(path.read_text(encoding='utf-8'))]
    assert not found, ('docstrings carry bench figures (move them to a dated report under '
                       'docs/bench/, keep the reason in words):\n' + '\n'.join(found))
