"""``tlessbot evaluate`` with the pipeline's stage clock read as the process's CPU time (every
thread) instead of the wall clock, so that report.md's timing lines compare trees run on a
shared, loaded host (the wall clock there follows the other jobs more than the code).

    PYTHONPATH=TREE python scripts/evaluate_cpu_clock.py evaluate --dataset D --models M ...

The arguments are those of ``tlessbot``; the figures are CPU milliseconds (threads that wait
on a lock or spin count as they burn), comparable between trees only.
"""
import runpy
import sys
import time
import types

import tlessbot_ros.core.pipeline as pipeline

clock = types.SimpleNamespace(**{name: getattr(time, name) for name in dir(time)
                                 if not name.startswith('__')})
clock.perf_counter = time.process_time
pipeline.time = clock   # type: ignore[assignment]
sys.argv = ['tlessbot', *sys.argv[1:]]
runpy.run_module('tlessbot_ros.tools.cli', run_name='__main__')
