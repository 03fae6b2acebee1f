"""The fast subset of the fuzz matrix (bench/fuzz.py has all of it): each run is `sclam
calibrate` or `sclam calibrate --track` in a subprocess, as a user runs it, on a bad
recording made by test/fuzz_cases.py, and must give what its case declares: the error
named, the problem warned about with a right estimate, or a clean right estimate. Never a
traceback, never a NaN, never silently wrong."""
import re
from concurrent.futures import ProcessPoolExecutor

import fuzz_cases as fuzz
import pytest

# Shorter than the bench's recordings: the subset must stay within about a minute.
DURATION = 25.0
RUNS = [(name, mode) for name, case in fuzz.CASES.items() for mode in case.fast]


def _run(args):
    name, sources, work, mode = args
    return fuzz.run(fuzz.CASES[name], sources, work, track=mode == "track")


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    """Every run of the subset, two at a time (each is a process of its own anyway)."""
    sources = tmp_path_factory.mktemp("sources")
    work = tmp_path_factory.mktemp("cases")
    for name in sorted({fuzz.CASES[name].source for name, _ in RUNS}):
        fuzz.make_source(name, sources, duration=DURATION)
    with ProcessPoolExecutor(2) as pool:
        results = pool.map(_run, [(name, sources, work, mode) for name, mode in RUNS])
        return dict(zip(RUNS, results))


def test_the_subset_covers_each_kind_of_case():
    expected = {fuzz.CASES[name].expect for name, _ in RUNS}
    assert expected == {"clean", "error", "warning", "unobservable"}
    assert {mode for _, mode in RUNS} == {"batch", "track"}


@pytest.mark.parametrize("name,mode", RUNS, ids=[f"{n}-{m}" for n, m in RUNS])
def test_case_gives_what_it_declares(outcomes, name, mode):
    case, outcome = fuzz.CASES[name], outcomes[name, mode]
    assert outcome.kind not in ("traceback", "nan"), outcome.detail
    assert fuzz.judge(case, outcome), (case.expect, case.needles, outcome)


def test_track_refuses_miswired_encoders_like_batch(outcomes):
    """--track used to write absurd numbers for swapped wheels (issue 13): now the batch
    solve's wiring check refuses it with the same reason."""
    batch, track = outcomes["swapped_wheels", "batch"], outcomes["swapped_wheels", "track"]
    assert batch.kind == track.kind == "error"
    # The same words and fix; the correlations quoted differ in the last digit (the batch
    # run also has the keyframes its end-of-recording flush makes).
    assert re.sub(r"[-+]\d\.\d+", "#", batch.detail) == re.sub(r"[-+]\d\.\d+", "#", track.detail)
    assert "set left_wheel_joint: right_wheel_joint, right_wheel_joint: left_wheel_joint" in track.detail
