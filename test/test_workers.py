"""The automatic choice of `sclam calibrate --workers` (fleet/workers.py): behaviour only."""
from sclam_ros.fleet.workers import WorkersConfig, choose_workers

CONFIG = WorkersConfig(parallel_from_s=60.0)


def test_auto_is_sequential_below_the_threshold_and_parallel_from_it():
    assert choose_workers("auto", 59.0, cores=2, config=CONFIG).workers == 1
    assert choose_workers("auto", 60.0, cores=2, config=CONFIG).workers == 2
    assert choose_workers("auto", 600.0, cores=8, config=CONFIG).workers == 8


def test_auto_never_cuts_more_chunks_than_the_recording_has_room_for():
    # chunked.MIN_CHUNK_S = 20 s each
    assert choose_workers("auto", 70.0, cores=8, config=CONFIG).workers == 3


def test_auto_on_one_core_is_sequential():
    assert choose_workers("auto", 600.0, cores=1, config=CONFIG).workers == 1


def test_a_number_forces_the_choice():
    assert choose_workers(1, 600.0, cores=2, config=CONFIG).workers == 1
    assert choose_workers(2, 50.0, cores=2, config=CONFIG).workers == 2
    assert choose_workers(3, 600.0, cores=2, config=CONFIG).workers == 3
    assert choose_workers(4, 50.0, cores=8, config=CONFIG).workers == 2  # room for two


def test_the_reason_says_what_was_chosen_and_why():
    short = choose_workers("auto", 30.0, cores=2, config=CONFIG).reason
    long = choose_workers("auto", 600.0, cores=2, config=CONFIG).reason
    assert "sequentially" in short and "30 s" in short and "60 s" in short
    assert "2 parallel chunks" in long and "600 s" in long
