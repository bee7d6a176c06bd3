import json
import os
import subprocess
import sys

from tlessbot_ros.nodes.common import BLAS_THREAD_VARIABLES

PROBE = """
import json, numpy
from threadpoolctl import threadpool_info
from tlessbot_ros.nodes.common import limit_blas_threads
limit = limit_blas_threads()
blas = [pool['num_threads'] for pool in threadpool_info() if pool['user_api'] == 'blas']
print(json.dumps({'limit': limit, 'blas': blas}))
"""


def _probe(**env_extra):
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env.update(env_extra)
    out = subprocess.run([sys.executable, '-c', PROBE], env=env, capture_output=True,
                         text=True, check=True, timeout=60)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_nodes_run_blas_on_one_thread_unless_the_user_chose():
    default = _probe()
    assert default['limit'] == 1 and default['blas'] and set(default['blas']) == {1}
    chosen = _probe(OPENBLAS_NUM_THREADS='2')
    assert chosen['limit'] is None
