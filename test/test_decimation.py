"""Which scans are matched (frontend/decimation.py): about DecimationConfig.match_period apart at any rate,
the same scans whether reading starts at the recording's start or in the middle."""
import numpy as np
import pytest

from sclam_ros.frontend.config import DecimationConfig
from sclam_ros.frontend.decimation import ScanDecimator

MATCH_PERIOD = DecimationConfig().match_period
RATE_SAMPLE = DecimationConfig().rate_sample


def accepted(stamps):
    decimator = ScanDecimator()
    return [t for t in stamps if decimator.accept(t)], decimator


@pytest.mark.parametrize("rate", [4.0, 5.0, 10.0, 12.5, 25.0, 40.0])
def test_matched_scans_are_about_the_match_period_apart(rate):
    # A real laser's period is a hair off its nominal one (5 Hz: 0.2000001 s).
    period = 1.0 / rate * (1 + 1e-7)
    stamps = 1.7e9 + period * np.arange(int(60 * rate))
    kept, decimator = accepted(stamps)
    # (the first grid scan after the rate sample may follow the sample's last scan closely)
    spacing = np.diff(kept[RATE_SAMPLE + 2:])
    # Every n-th scan, n the nearest whole number of periods to MATCH_PERIOD (halves up):
    # never closer than half the match period, never farther than 1.5 of it or one period.
    expected = max(1, int(np.floor(MATCH_PERIOD * rate + 0.5)))
    assert decimator.every == expected
    assert np.allclose(spacing, expected * period, atol=1e-5)  # stamps near 1.7e9 s: ~0.2 µs steps
    assert spacing.min() >= min(0.5 * MATCH_PERIOD, period) - 1e-9
    assert decimator.skipped == len(stamps) - len(kept)
    assert not decimator.follows_samples  # no encoder samples given


def test_a_chunk_read_from_the_middle_matches_the_same_scans():
    period = 0.1 + 1.3e-7
    stamps = 1.7e9 + 0.0437 + period * np.arange(3000)
    whole, _ = accepted(stamps)
    chunk, _ = accepted(stamps[1234:])
    # After the chunk's rate sample and the first grid scan that closes it.
    after_warmup = set(chunk[RATE_SAMPLE + 2:])
    assert after_warmup and after_warmup <= set(whole)


@pytest.mark.parametrize("encoder_rate", [1.0, 2.0])
def test_slow_encoders_get_the_scan_after_each_sample_matched(encoder_rate):
    """Odometry at 1-2 Hz, a 10 Hz laser whose scans come 13 ms after the samples: the scan
    right after every sample is matched (its wheel angles are 13 ms of straight line from a
    sample), and between samples the scans are no closer than half the match period."""
    period, sample_period = 0.1, 1.0 / encoder_rate
    decimator = ScanDecimator()
    kept, samples = [], []
    for i in range(600):
        stamp = 1.7e9 + 0.013 + period * i
        samples = [t for t in 1.7e9 + sample_period * np.arange(int(60 * encoder_rate) + 1)
                   if t <= stamp]
        if decimator.accept(stamp, samples[-1], sample_period):
            kept.append(stamp)
    after = kept[RATE_SAMPLE + 1:]
    sample_times = 1.7e9 + sample_period * np.arange(3, int(60 * encoder_rate))
    for t in sample_times[sample_times > after[0]]:
        assert any(abs(k - (t + 0.013)) < 1e-6 for k in after), t
    assert np.diff(after).min() >= 0.5 * MATCH_PERIOD - 1e-6
    assert decimator.skipped == 600 - len(kept)
    assert decimator.follows_samples  # `sclam calibrate` says so


def test_a_reader_given_the_recordings_scan_period_matches_the_same_scans_from_its_middle():
    """A jittery laser (a real log's stamps): a decimator that measures the period on its
    own first scans in the middle lays another grid; given the period measured on the
    recording's first scans (scan_period, as fleet/chunked.py does) it matches the scans
    a sequential pass does."""
    from sclam_ros.frontend.decimation import scan_period

    rng = np.random.default_rng(1)
    stamps = 1.7e9 + np.cumsum(rng.uniform(0.09, 0.106, 3000))
    sequential, _ = accepted(stamps)
    middle = 1500
    given = ScanDecimator(scan_period=scan_period(stamps[:RATE_SAMPLE + 1]))
    from_middle = [t for t in stamps[middle:] if given.accept(t)]
    # (its first scan opens a bin, as in any reader; from the next on, the grid decides)
    assert from_middle[1:] == [t for t in sequential if t >= from_middle[1]]
    measuring, _ = accepted(stamps[middle:])
    assert not set(measuring[RATE_SAMPLE + 2:]) <= set(sequential)
