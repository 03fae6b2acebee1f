import os
import sys
from pathlib import Path

# Tests import helpers (numdiff, ...) that live beside them.
sys.path.insert(0, str(Path(__file__).parent))
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("MPLBACKEND", "Agg")
