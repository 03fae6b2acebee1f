"""Where `sclam calibrate` spends its time, by stage, and the floor it is measured against.

profile(bag): the command a user types (sequential) run once in a fresh process, sampled:
every millisecond a timer signal's handler looks at the stack and adds the time since its
last look to the stage of the innermost function it knows there (STAGES; a stack inside an
import is start-up). Start-up is also everything before the command's main (the
interpreter, the first imports); the report is what is left of the command (the
parameters, the printed table, --json). Sampled, not cProfile: cProfile's cost per Python
call doubled the run and fell mostly on the stages of many small calls. Python runs the
handler between two of its instructions, so a sample due during KISS-ICP's C++ is taken
right after it returns, still inside the function that called it: its time goes to the
right stage.

floor(bag): what any calibration from this recording costs at least, in one fresh process:
reading every message of the two input topics (rosbags, deserialised), and KISS-ICP alone
(its KissICP pipeline, configured as the front end configures it: voxel size, points per
voxel, threshold, iterations; deskewing off, as for a 2D laser) on the scans the
calibration registers (the decimator's), converted to points. KISS-ICP alone predicts each
scan from its constant-velocity model, where the front end seeds it from the wheels.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = str(Path(__file__).resolve().parents[1])

# (file ending, function) -> stage; the innermost on the stack wins
STAGES = {
    ("io/bag.py", "iter_messages"): "reading", ("io/bag.py", "topic_info"): "reading",
    ("io/bag.py", "_time_span_ns"): "reading", ("io/bag.py", "open_reader"): "reading",
    ("io/messages.py", "laser_scan_to_scan"): "scan conversion",
    ("io/messages.py", "check_scan"): "scan conversion",
    ("frontend/scan_matching.py", "thinned"): "scan conversion",
    ("frontend/scan_matching.py", "scan_to_points"): "scan conversion",
    ("frontend/scan_matching.py", "add_scan"): "registration (KISS-ICP)",
    ("frontend/point_to_line.py", "add_scan"): "refinement (point-to-line)",
    ("io/recording.py", "read_recording"): "encoders and synchronisation",
    ("core/estimator.py", "check_wiring"): "graph building",
    ("core/graph.py", "merge_keyframes"): "graph building",
    ("core/graph.py", "from_keyframes"): "graph building",
    ("core/graph.py", "build_problem"): "graph building",
    ("core/estimator.py", "calibrate_keyframes"): "solving",
    ("core/covariance.py", "remaining_step"): "covariances",
    ("core/covariance.py", "of"): "covariances",
    ("core/correlated_covariance.py", "chain_correlated_covariance"): "covariances",
    ("core/correlated_covariance.py", "sandwich_covariance"): "covariances",
    ("core/dilution.py", "summary"): "covariances",
    ("core/estimator.py", "residual_rms"): "covariances",
}
START_UP = "start-up (interpreter, imports)"
ORDER = [START_UP, "reading", "scan conversion", "registration (KISS-ICP)",
         "refinement (point-to-line)", "encoders and synchronisation", "graph building",
         "solving", "covariances", "report"]

SAMPLED = r"""
import json, signal, sys, time
sys.path.insert(0, {root!r})
sys.path.insert(0, {bench!r})
begin = time.perf_counter()
from stage_profile import STAGES, START_UP
from sclam_ros.cli.main import main
seconds, by_name = {{}}, {{}}
for (ending, name), stage in STAGES.items():
    by_name.setdefault(name, []).append((ending, stage))

def stage_of(frame):
    found = None
    while frame is not None:
        code = frame.f_code
        if code.co_name == "_find_and_load":
            return START_UP
        if found is None:
            for ending, stage in by_name.get(code.co_name, ()):
                if code.co_filename.endswith(ending):
                    found = stage
        frame = frame.f_back
    return found or "report"

last = time.perf_counter()

def sample(signum, frame):
    global last
    now = time.perf_counter()
    stage = stage_of(frame)
    seconds[stage] = seconds.get(stage, 0.0) + now - last
    last = now

signal.signal(signal.SIGALRM, sample)
start = last = time.perf_counter()
signal.setitimer(signal.ITIMER_REAL, 0.001, 0.001)
main({argv!r})
signal.setitimer(signal.ITIMER_REAL, 0.0)
end = time.perf_counter()
sample(None, None)
seconds["report"] = seconds.get("report", 0.0)
print(json.dumps(dict(before_main=start - begin, main=end - start, seconds=seconds)))
"""

FLOOR = r"""
import json, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import KissICP
from sclam_ros.core.params import SclamParams
from sclam_ros.frontend.decimation import ScanDecimator
from sclam_ros.frontend.scan_matching import ScanMatcherConfig, scan_to_points, thinned
from sclam_ros.io import bag
from sclam_ros.io.messages import laser_scan_to_scan
params = SclamParams.from_yaml({params!r})
start = time.perf_counter()
scans = [msg for topic, _, msg in bag.iter_messages({bag!r}, [params.joint_states_topic,
                                                              params.scan_topic])
         if topic == params.scan_topic]
read = time.perf_counter()
c = ScanMatcherConfig.from_params(params)
decimator, frames = ScanDecimator(), []
for msg in scans:
    scan = laser_scan_to_scan(msg)
    if decimator.accept(scan.stamp):
        frames.append(scan_to_points(thinned(scan, params.scan_max_beams), c.min_range, c.max_range))
converted = time.perf_counter()
config = KISSConfig(
    data={{"max_range": c.max_range, "min_range": c.min_range, "deskew": False}},
    mapping={{"voxel_size": c.voxel_size, "max_points_per_voxel": c.max_points_per_voxel}},
    registration={{"max_num_iterations": c.max_iterations, "convergence_criterion": c.convergence,
                   "max_num_threads": c.max_threads}},
    adaptive_threshold={{"fixed_threshold": c.fixed_threshold}})
odometry = KissICP(config)
for frame in frames:
    odometry.register_frame(frame, np.zeros(0))
end = time.perf_counter()
print(json.dumps(dict(reading=read - start, conversion=converted - read, kiss_icp=end - converted,
                      scans=len(frames))))
"""


def _child(code):
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1]), time.perf_counter() - start


def floor(bag) -> dict:
    """{reading, conversion, kiss_icp: s, scans: registered, total: s} of the floor."""
    result, _ = _child(FLOOR.format(root=ROOT, bag=str(bag), params=str(Path(bag) / "params.yaml")))
    result["total"] = result["reading"] + result["conversion"] + result["kiss_icp"]
    return result


def profile(bag) -> dict:
    """{stage: s} of one sampled `sclam calibrate --workers 1` run, in ORDER, and its "wall"
    (s, the process's, interpreter start included)."""
    argv = ["calibrate", str(bag), "--params", str(Path(bag) / "params.yaml"), "--quiet",
            "--json", str(Path(bag) / "profiled.json"), "--workers", "1"]
    run, wall = _child(SAMPLED.format(root=ROOT, bench=str(Path(__file__).parent), argv=argv))
    seconds = {stage: run["seconds"].get(stage, 0.0) for stage in ORDER}
    seconds[START_UP] += wall - run["main"]
    return {"wall": wall, **seconds}
