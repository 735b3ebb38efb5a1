"""The C++ masters' runners (libcosim, its ECCO, Ecos) hold the calling thread to one core
while the master is made and run (``cosim.threads.one_core``; docs/performance.md,
"libcosim's step on an idle machine"): the master's threads inherit that, and every core
is given back after."""
from __future__ import annotations

import os

import pytest

pytest.importorskip("libcosimpy")
pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs thread affinity and two cores")

from mbdfmu.cosim import ecco_runner, ecos_runner, libcosim_runner, threads  # noqa: E402
from mbdfmu.cosim.settings import CosimError  # noqa: E402
from test_cosim_coupling import built  # noqa: E402,F401  (the scenarios' FMUs, built once)


def watch(monkeypatch, module, name, fail=False):
    """Replace module.name by a call that records the thread's cores, then runs it (or
    raises CosimError)."""
    seen, inner = [], getattr(module, name)

    def watched(*args, **kwargs):
        seen.append(os.sched_getaffinity(0))
        if fail:
            raise CosimError("stopped")
        return inner(*args, **kwargs)
    monkeypatch.setattr(module, name, watched)
    return seen


def test_libcosim_runs_on_one_core_and_gives_the_cores_back(built, monkeypatch):
    scenario, fmus = built("dc_motor_slider_crank")
    before = os.sched_getaffinity(0)
    seen = watch(monkeypatch, libcosim_runner, "_record")
    libcosim_runner.run_libcosim(scenario, fmus, step=1e-3, t_end=5e-3)
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0] <= before
    assert os.sched_getaffinity(0) == before


def test_a_failing_libcosim_run_gives_the_cores_back(built, monkeypatch):
    scenario, fmus = built("dc_motor_slider_crank")
    before = os.sched_getaffinity(0)
    seen = watch(monkeypatch, libcosim_runner, "_record", fail=True)
    with pytest.raises(CosimError, match="stopped"):
        libcosim_runner.run_libcosim(scenario, fmus, step=1e-3, t_end=5e-3)
    assert len(seen[0]) == 1 and os.sched_getaffinity(0) == before


def test_ecco_runs_on_one_core_and_gives_the_cores_back(built, monkeypatch):
    scenario, fmus = built("quarter_car")
    before = os.sched_getaffinity(0)
    seen = watch(monkeypatch, ecco_runner, "_simulate")
    ecco_runner.run_ecco(scenario, fmus, step=2e-3, t_end=0.01, rtol=1e-2, atol=1e-2)
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0] <= before
    assert os.sched_getaffinity(0) == before


def test_ecos_runs_on_one_core_and_gives_the_cores_back(built, monkeypatch, tmp_path):
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    scenario, fmus = built("dc_motor_slider_crank")
    before = os.sched_getaffinity(0)
    seen = watch(monkeypatch, ecos_runner, "_run")
    ecos_runner.run_ecos(scenario, fmus, tmp_path / "e.ssp", step=1e-3, t_end=5e-3)
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0] <= before
    assert os.sched_getaffinity(0) == before


def test_parallel_runs_spread_over_the_cores(monkeypatch):
    """The core follows the process id: two processes side by side get different cores."""
    cores = sorted(os.sched_getaffinity(0))
    got = []
    for pid in (100, 101):
        monkeypatch.setattr(os, "getpid", lambda pid=pid: pid)
        with threads.one_core():
            got.append(os.sched_getaffinity(0))
    assert got == [{cores[100 % len(cores)]}, {cores[101 % len(cores)]}]
