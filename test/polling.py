"""Waiting on a live ROS graph: poll a condition until it holds or a timeout passes."""
import time


def wait_for(condition, timeout, what="condition", interval=0.01):
    """Return once condition() is true; AssertionError after `timeout` s. `interval` is how
    often the condition is polled, not a synchronisation."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)
