"""The C++ masters' threads held to one core while they run mbdfmu's FMUs.

libcosim hands every step of every slave to worker threads, and Ecos steps its instances
on TBB's threads; on an idle machine a handoff to a thread on another core waits for that
core to wake, at every step. mbdfmu's FMUs are light (a step costs microseconds) and most
share the host's Python, so a second core gives them nothing and that wait was a large
part of each step (docs/performance.md, "libcosim's step on an idle machine"). Threads inherit the
affinity of the thread that starts them, so holding the calling thread to one core while
a master is made and run keeps the master's threads there too.
"""

from __future__ import annotations

import contextlib
import os


@contextlib.contextmanager
def one_core():
    """The calling thread (and the threads it starts) held to one of the cores it may use,
    its affinity given back on leaving; nothing where the platform cannot (not Linux).
    The core is chosen by the process id, so runs in parallel processes spread over the
    cores instead of sharing the first."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    allowed = os.sched_getaffinity(0)
    cores = sorted(allowed)
    os.sched_setaffinity(0, {cores[os.getpid() % len(cores)]})
    try:
        yield
    finally:
        os.sched_setaffinity(0, allowed)
