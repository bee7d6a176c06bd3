"""Whether two evaluate outputs hold the same estimates, frame by frame (the time column aside).

    python scripts/estimates_same.py A/estimates.csv B/estimates.csv

Prints each frame whose estimates differ (rows only in A, only in B) and a count line; exits 1
when any frame differs. docs/bench/determinism.md.
"""
from __future__ import annotations

import csv
import sys
from collections import defaultdict
from pathlib import Path


def _rows(path: Path) -> dict[tuple[str, str], list[tuple[str, ...]]]:
    """{(scene_id, im_id): sorted rows without the time column}."""
    frames: dict[tuple[str, str], list[tuple[str, ...]]] = defaultdict(list)
    with path.open(newline='') as f:
        for row in csv.DictReader(f):
            frames[row['scene_id'], row['im_id']].append(
                (row['obj_id'], row['score'], row['R'], row['t']))
    return {k: sorted(v) for k, v in frames.items()}


def main(argv: list[str]) -> int:
    a, b = (_rows(Path(p)) for p in argv[:2])
    frames = sorted(set(a) | set(b), key=lambda k: (int(k[0]), int(k[1])))
    differ = 0
    for key in frames:
        rows_a, rows_b = a.get(key, []), b.get(key, [])
        if rows_a != rows_b:
            differ += 1
            only_a = sorted(set(rows_a) - set(rows_b))
            only_b = sorted(set(rows_b) - set(rows_a))
            print(f'scene {key[0]} im {key[1]}: {len(only_a)} rows only in A, '
                  f'{len(only_b)} only in B (objs {[r[0] for r in only_a]} / '
                  f'{[r[0] for r in only_b]})')
    print(f'{differ} of {len(frames)} frames differ')
    return 1 if differ else 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
