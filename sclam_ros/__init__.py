"""sclam_ros: simultaneous calibration, localization and mapping for differential-drive robots."""
import os
import sys

# Our dense products are small (the online window: ~230 columns) and the big solves are
# banded: BLAS threads only contend with KISS-ICP's own threads, the node's callbacks and
# each other (docs/decisions/runtime.md). A user's explicit setting wins.
_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_explicit = any(var in os.environ for var in _BLAS_THREAD_VARIABLES)
for _var in _BLAS_THREAD_VARIABLES:
    os.environ.setdefault(_var, "1")
if "numpy" in sys.modules and not _explicit:
    # numpy came first (a script that imports it before us): its BLAS read the variables
    # already, so limit its threads directly.
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")

__version__ = "0.1.0"
