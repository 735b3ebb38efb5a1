"""rk4p's step-doubling checks in the C kernel (ckernel/fixed.h, issue 13): rk4p's runs and
an FMU's rk4p doSteps stay in C through the checks of the stated accuracy, and reach the
same decisions, the same estimate and the same stop (time and reason) as the Python rule
of ``stated_accuracy.py``, the reference, which these tests run side by side."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest

import exact_solutions as ref
import mbdfmu
from mbdfmu import fast_steps
from mbdfmu.equations import ckernel
from mbdfmu.integrators import rk4p_c
from mbdfmu.model.reader import bundled_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fmu_models.harness import ERROR, OK  # noqa: E402
from fmu_models.scenes import scene_host  # noqa: E402,F401

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
ADVANCE_IN_C, C_TURNS = rk4p_c.advance_fixed, rk4p_c._turns


def simulation(name: str, step: float, in_c: bool, monkeypatch, audit: bool = True):
    """rk4p on a bundled scene in the C kernel, its loop (steps and checks) in C or, with
    ``in_c`` False, Python's loop of ``stated_accuracy.py``; and a list of the calls into
    the C loop."""
    taken = []

    def turns(*args):
        taken.append(args[3])
        return C_TURNS(*args)
    monkeypatch.setattr(rk4p_c, "_turns", turns)
    monkeypatch.setattr(rk4p_c, "advance_fixed", ADVANCE_IN_C if in_c else
                        lambda rk, t_target: False)
    sim = mbdfmu.Simulation(mbdfmu.load_scene(bundled_scene(name)), method="rk4p",
                            kernel="c", step=step)
    if not audit:
        sim.integrator.audit = None
    return sim, taken


def state(sim) -> tuple:
    rk = sim.integrator
    return (rk.t, rk.q.tobytes(), rk.qd.tobytes(), vars(rk.stats), vars(rk.accuracy))


def advance_both(name, step, times, monkeypatch, audit=True) -> tuple:
    """Both loops over ``times``: (their states or stop messages, the C loop's advances)."""
    outcomes = []
    for in_c in (False, True):
        sim, taken = simulation(name, step, in_c, monkeypatch, audit)
        try:
            for t in times:
                sim.advance(t)
            outcomes.append(state(sim))
        except mbdfmu.SolverError as exc:
            outcomes.append(str(exc))
    return outcomes, len(taken)


def test_p2_runs_keep_pythons_estimate_and_bound_the_error(monkeypatch):
    """P2 N = 2 over 10 s at h = 10 ms in one advance and at 1 ms in 1 ms advances: the
    same state, counters and estimate bit for bit (hundreds of checks, their intervals
    doubling and halving), and the estimate still bounds the error against the exact
    one-degree-of-freedom reduction (tests/exact_solutions.py)."""
    (python, c), taken = advance_both("n_four_bar_2", 0.01, [10.0], monkeypatch)
    assert taken == 1 and python == c
    sim, _ = simulation("n_four_bar_2", 0.01, True, monkeypatch)
    sim.advance(10.0)
    out, exact = sim.outputs(), ref.n_four_bar(np.array([10.0]), 2)
    phi = out["crank0.phi"]
    error = np.hypot(out["crank0.x"] + 0.5 * np.cos(phi) - exact["B0_x"][0],
                     out["crank0.y"] + 0.5 * np.sin(phi) - exact["B0_y"][0])
    assert error <= sim.integrator.stats.error_estimate <= 200 * error
    # 1 ms advances (an FMU's pattern): the C loop takes those a check falls in
    (python, c), taken = advance_both("n_four_bar_2", 1e-3, np.arange(1, 1001) * 1e-3,
                                      monkeypatch)
    assert python == c and taken >= 5


def test_a_p2_run_beyond_its_stated_accuracy_stops_where_pythons_does(monkeypatch):
    """rk4p at h = 0.1 s on P2 N = 2 (B0 0.13 m off by 10 s before the estimate): the C loop
    stops at the same time with the same estimate and reason."""
    (python, c), taken = advance_both("n_four_bar_2", 0.1, [10.0], monkeypatch)
    assert taken == 1
    assert c == python and "t = 1.6 s: rk4p: estimated error 0.0264" in c


def test_andrews_at_half_a_millisecond_stops_where_pythons_does(monkeypatch):
    """Andrews' mechanism at h = 0.5 ms, 1 ms advances: its local error peaks between checks
    (what the envelope is for); the run stops at t = 0.02 s, as tests/
    test_fixed_step_estimate.py asserts of Python's loop, with the same estimate, with
    and without its energy check (a spring's energy, which the kernel checks too:
    stepping.h total_energy)."""
    times = np.arange(1, 31) * 1e-3
    for audit in (False, True):
        (python, c), taken = advance_both("andrews", 5e-4, times, monkeypatch, audit=audit)
        assert taken >= 5
        assert c == python and c.startswith("t = 0.02 s: rk4p: estimated error 0.0109")


def test_the_wrappers_rk4p_steps_keep_pythons_estimate():
    """The slider-crank as its FMU steps it: the wrapper's doSteps (mbd_fixed_step, 1 ms and
    some 3 ms, so that checks fall inside doSteps) take every check in C, and the
    Simulation that catches up has Python's state, counters and estimate bit for bit."""
    scene = mbdfmu.load_scene(bundled_scene("slider_crank"))
    python, wrapper = (mbdfmu.Simulation(scene, method="rk4p", kernel="c") for _ in "ab")
    ends = np.cumsum([3e-3 if k % 10 == 9 else 1e-3 for k in range(600)])
    for t in ends:
        python.advance(t)
    wrapper.advance(ends[0])                 # the slave's Python step, then the wrapper's
    none = np.zeros(0, dtype=np.int64)
    armed = fast_steps.arm(wrapper, None, 1e-9, (none, none), (none, none))
    step, model, context = armed[:3]
    call = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_double, ctypes.c_void_p)(step)
    values = np.zeros(1)
    for start, end in zip(ends[:-1], ends[1:]):
        assert call(model, context, start, end - start, values.ctypes.data) == 0
    moved, _, _ = fast_steps.catch_up(wrapper, (none, none))
    assert moved and wrapper.integrator.accuracy.every > 4      # checks were taken
    assert state(wrapper) == state(python)


CRANE = Path(__file__).resolve().parents[1] / "scenarios" / "hydraulic_crane" / "crane.toml"


def test_the_wrapper_hands_back_the_step_that_passes_the_allowance(scene_host, tmp_path):
    """The crane's mechanism with rk4p at 20 ms steps (its scene's rtol 1e-9) and the
    cylinder force set before every 20 ms doStep: the wrapper takes the doSteps and their
    checks, and the one in which the estimate passes the allowance goes to Python, which
    stops there (fmi2Error) with the message an instance sent through Python at every step
    gives, at the same time (after 1 s: the stop comes at t = 1.3 s in a Simulation run
    with the force set at each step's end instead)."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    scene = tmp_path / "crane.toml"
    scene.write_text(CRANE.read_text().replace('method = "dop853p"', 'method = "rk4p"'))
    path = build_fmu(scene, tmp_path / "crane.fmu")
    hosts = [scene_host(path, name) for name in ("fast", "slow")]
    for h in hosts:
        assert h.status("fmi2SetReal", (ctypes.c_uint * 1)(h.vr["solver.step"]), 1,
                        (ctypes.c_double * 1)(0.02)) == OK
        h.init()
    fast, slow = hosts
    force = [fast.vr["cylinder.actuator"]]
    codes = [OK, OK]
    while codes == [OK, OK] and fast.t < 2.0:
        for h in hosts:
            assert h.set_real(force, [8420.0 * (1.0 + 0.05 * np.sin(2.0 * np.pi * h.t))]) == OK
        codes = [h.step(0.02) for h in hosts]
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
        if codes == [OK, OK]:
            assert fast.real("boom.phi") == slow.real("boom.phi")
    assert codes == [ERROR, ERROR] and fast.t == slow.t
    stop = [h.messages[-1][2] for h in hosts]
    assert stop[0] == stop[1]
    assert f"t = {fast.t + 0.02:g} s: rk4p: estimated error" in stop[0] and 1.0 < fast.t < 2.0
    taken = sum(int(m.split(": ")[1].split()[0]) for _, _, m in fast.messages
                if "taken by the wrapper" in m)
    assert taken >= 60
