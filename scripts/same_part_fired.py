"""Where the same-part rule fires: ``tlessbot evaluate`` with a line for each pair it joins.
docs/bench/smoothed-false-boxes-ninth.md.

    python scripts/same_part_fired.py EVALUATE ARGUMENTS...

Prints ``SAME <frame> <instance a> <instance b> <class>`` each time the fragment filter's
``same(a, b)`` (``core.same_part.same_part_test``) answers yes, counting frames from 0 in the
order `evaluate` runs them, between its progress lines.
"""
from __future__ import annotations

import sys

import tlessbot_ros.core.one_part as one_part
from tlessbot_ros.core.pipeline import PerceptionPipeline

_original_test = one_part.same_part_test
_original_process = PerceptionPipeline.process
_frame = [-1]
_said: set[tuple[int, int, int]] = set()


def _test(*args, **kwargs):
    same = _original_test(*args, **kwargs)
    if same is None:
        return None

    def spy(a, b):
        answer = same(a, b)
        key = (_frame[0], *sorted((a.instance_id, b.instance_id)))
        if answer and key not in _said:
            _said.add(key)
            print('SAME', *key, a.obj_id, flush=True)
        return answer
    return spy


def _process(self, *args, **kwargs):
    _frame[0] += 1
    return _original_process(self, *args, **kwargs)


if __name__ == '__main__':
    one_part.same_part_test = _test
    PerceptionPipeline.process = _process
    from tlessbot_ros.tools.cli import main
    sys.exit(main(['evaluate', *sys.argv[1:]]) or 0)
