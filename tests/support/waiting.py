"""waiting: the one poll-until-true helper of the Python tests and tools.

The tests wait for conditions with generous deadlines, never for a fixed time
before a check (make test-stress runs them beside a CPU hog). No imports beyond
the standard library, so scripts/cluster can use it without the client package.
"""
import time


def wait_for(cond, timeout, step=0.05):
    """Poll cond() until it returns something true or timeout s have passed;
    returns its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(step)
    return cond()
