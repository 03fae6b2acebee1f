"""sclam_ros: simultaneous calibration, localization and mapping for differential-drive robots."""
import os

# Our dense products are thin (n × 6) and the big solves are banded: BLAS threads only
# contend with KISS-ICP's own threads and each other. Measured on the 2-core target: a
# 40-column banded solve took 385 ms with OpenBLAS threading, 22 ms with one thread.
# Set before numpy is first imported; a user's explicit setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
