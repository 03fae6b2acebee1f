"""sclam_ros runs BLAS on one thread, even when a script imported numpy first.

With two OpenBLAS threads the online window solve (dense, ~230 columns) competed with the
node's own callbacks on a 2-core machine: its p99 went from 13 to 30 ms
(bench/node_latency.py, which imports numpy before sclam_ros)."""
import os
import subprocess
import sys

PROBE = """
import numpy
import sclam_ros
from threadpoolctl import threadpool_info
print(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
"""


def _blas_threads(env_update):
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(env_update)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True,
                         text=True, check=True)
    return int(out.stdout.split()[-1])


def test_one_blas_thread_even_if_numpy_came_first():
    assert _blas_threads({}) == 1


def test_an_explicit_setting_wins():
    assert _blas_threads({"OPENBLAS_NUM_THREADS": "2"}) == 2
