import os
import sys
from pathlib import Path

# Tests import helpers (numdiff, ...) that live beside them.
sys.path.insert(0, str(Path(__file__).parent))
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("MPLBACKEND", "Agg")


def pytest_configure(config):
    # Tests that simulate and replay minutes of driving (tens of seconds each):
    # `-m "not heavy"` leaves them out of a quick run.
    config.addinivalue_line("markers", "heavy: simulates and replays minutes of driving")
