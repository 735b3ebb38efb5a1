"""FMI 3.0 FMUs take the same fast paths as FMI 2.0 ones (tests/test_fmu_fast.py): the
wrapper takes fmi3DoStep (dense-output reads, rk4p with drivers, embedded-pair landing
steps) and fmi3SetFloat64 of force inputs without Python, with fmi3DoStep's outputs as
the standard asks (no event, no termination, no early return, lastSuccessfulTime
t + h), and every value bit for bit what Python computes: a "fast" instance beside a
"slow" one whose every next call goes through Python (fmi3SetDebugLogging after each
step), in fmpy's FMU3Slave."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

pytest.importorskip("fmpy")
from fmu_models.fmi3_host import DISCARD, OK, Host3  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
H = 1e-3
CRANE = ROOT / "scenarios" / "hydraulic_crane" / "crane.toml"
DRIVEN = ROOT / "scenarios" / "prescribed_motion" / "slider_crank.toml"


@pytest.fixture(scope="module")
def fmu3(tmp_path_factory):
    """The FMI 3.0 FMU of a shipped scene, or of the crane or the driven slider-crank with
    the C kernel built for its scene (the FMI 3.0 wrapper's steps on it), built once."""
    root, built = tmp_path_factory.mktemp("fmi3_fast"), {}

    def get(stem: str) -> Path:
        if stem not in built:
            scene = {"crane": CRANE, "driven": DRIVEN}.get(stem, ROOT / "scenes" / f"{stem}.toml")
            built[stem] = build_fmu(scene, root / f"{stem}.fmu", fmi_version=3,
                                    scene_kernel=stem in ("crane", "driven"))
        return built[stem]
    return get


def taken_by_wrapper(h: Host3) -> int:
    """Communication steps the wrapper took without Python, as the slave logs them."""
    return sum(int(m.split(": ")[1].split()[0]) for _, _, m in h.messages
               if "taken by the wrapper" in m)


def through_python(h: Host3) -> None:
    """A call that makes the next doStep and gets Python's (the slave catches up first)."""
    assert h.status(lambda f: f.setDebugLogging(True, [])) == OK


def step_both(fast: Host3, slow: Host3, step: float, names) -> list[float]:
    """One fmi3DoStep of both, ``slow`` through Python: the same outputs of fmi3DoStep and
    the same values, bit for bit."""
    t = fast.t
    got, expected = fast.step(step), slow.step(step)
    assert got == expected == (OK, False, t + step), (fast.messages[-3:], slow.messages[-3:])
    values = fast.get(*names)
    assert values == slow.get(*names)
    through_python(slow)
    return values


def names_of(h: Host3) -> list[str]:
    """Outputs, the independent variable and the bodies' angles and accelerations."""
    return [v.name for v in h.md.modelVariables if v.causality == "output"] + ["time"] + \
        [n for n in h.vr if n.endswith((".alpha", ".ax", ".phi"))]


def replays(fast: Host3, path: Path, steps: int, names, force=None, value_at=None) -> None:
    """A state taken (and serialized) after the wrapper's steps restores, in the same and
    in a fresh instance, to values that go on bit for bit as before (the input ``force``
    set to ``value_at(t)``, default ``force_at``, before each step)."""
    value_at = value_at or force_at
    state, t = fast.fmu.getFMUState(), fast.t
    blob = fast.fmu.serializeFMUState(state)
    now = fast.get(*names)

    def ahead(h: Host3) -> np.ndarray:
        out = []
        for _ in range(steps):
            if force is not None:
                h.set(**{force: value_at(h.t)})
            assert h.step(H)[0] == OK
            out.append(h.get(*names))
        return np.array(out)
    first = ahead(fast)
    fast.fmu.setFMUState(state)
    fast.t = t
    assert fast.get(*names) == now
    np.testing.assert_array_equal(ahead(fast), first)
    other = Host3(path, "other").init()
    other.fmu.setFMUState(other.fmu.deserializeFMUState(blob))
    other.t = t
    np.testing.assert_array_equal(ahead(other), first)


def force_at(t: float) -> float:
    """The crane's cylinder force about holding the boom, swinging (N)."""
    return 8420.0 * (1.0 + 0.05 * np.sin(2.0 * np.pi * t))


@pytest.mark.parametrize("stem, steps, least", [("n_four_bar_2", 400, 300),
                                                 ("slider_crank", 300, 150)])
def test_fmi3_steps_are_the_wrappers_and_pythons_values(fmu3, stem, steps, least):
    """P2 N = 2 (dop853p: dense-output reads) and the slider-crank (rk4p with its motor
    evaluated in C; some 3 ms steps): the wrapper takes most fmi3DoSteps itself, and the
    values, the time and fmi3DoStep's outputs are Python's, also after a restored state."""
    fast, slow = Host3(fmu3(stem), "fast").init(), Host3(fmu3(stem), "slow").init()
    names = names_of(fast)
    for k in range(steps):
        step_both(fast, slow, 3 * H if k % 10 == 9 else H, names)
    through_python(fast)
    assert taken_by_wrapper(slow) == 0
    assert least <= taken_by_wrapper(fast) < steps
    assert fast.get(*names) == slow.get(*names)
    replays(fast, fmu3(stem), 5, names)


def test_fmi3_set_float64_of_a_force_and_the_landing_step_are_the_wrappers(fmu3):
    """The crane (dop853p) with its cylinder force set before every step: the wrapper takes
    fmi3SetFloat64 of the force and the step; a get between them goes through Python and
    agrees; a derivative input is Python's to take, and so are the steps it shapes."""
    fast, slow = Host3(fmu3("crane"), "fast").init(), Host3(fmu3("crane"), "slow").init()
    names = names_of(fast)
    for k in range(200):
        for h in (fast, slow):
            h.set(**{"cylinder.actuator": force_at(fast.t)})
        if k == 150:
            assert fast.get(*names) == slow.get(*names)
        step_both(fast, slow, 20 * H if k % 10 == 9 else H, names)
    through_python(fast)
    assert taken_by_wrapper(slow) == 0
    assert taken_by_wrapper(fast) >= 190
    before = taken_by_wrapper(fast)
    for h in (fast, slow):
        h.set(**{"der(cylinder.actuator)": 100.0})
    for _ in range(5):
        step_both(fast, slow, H, names)
    through_python(fast)
    assert taken_by_wrapper(fast) == before
    for h in (fast, slow):
        h.set(**{"der(cylinder.actuator)": 0.0})
    for _ in range(5):            # the force held again: the wrapper's steps
        for h in (fast, slow):
            h.set(**{"cylinder.actuator": force_at(fast.t)})
        step_both(fast, slow, H, names)
    through_python(fast)
    assert taken_by_wrapper(fast) > before
    replays(fast, fmu3("crane"), 5, names, "cylinder.actuator")


def test_fmi3_set_float64_of_a_driver_position_and_its_steps_are_the_wrappers(fmu3):
    """The prescribed-motion slider-crank (dop853p) with its crank angle set before every
    step, some steps 3 ms: the wrapper takes fmi3SetFloat64 of the position and the step
    (ckernel/motions.h), with Python's values bit for bit and the same warnings; a state
    taken after its steps holds the driver's samples and goes on as before, in the same
    and a fresh instance."""
    def angle(t):
        return 314.1592653589793 * t + 0.1 * np.sin(2.0 * np.pi * 5.0 * t)
    fast, slow = Host3(fmu3("driven"), "fast").init(), Host3(fmu3("driven"), "slow").init()
    names = names_of(fast)
    for k in range(200):
        for h in (fast, slow):
            h.set(**{"motor.position": angle(fast.t)})
        step_both(fast, slow, 3 * H if k % 10 == 9 else H, names)
    through_python(fast)
    assert taken_by_wrapper(slow) == 0
    # the doSteps where the derived acceleration's warning turns on or off are Python's
    # (the 3 ms steps among 1 ms ones make it turn)
    warned = [[m for _, _, m in h.messages if "derived from motor.position" in m]
              for h in (fast, slow)]
    assert warned[0] == warned[1] and warned[0]
    assert 199 - 2 * len(warned[0]) <= taken_by_wrapper(fast) < 199
    replays(fast, fmu3("driven"), 5, names, "motor.position", angle)


def test_fmi3_steps_beyond_the_work_limit_are_discarded_by_python(fmu3):
    """A step the wrapper cannot take within solver.max_steps_per_communication_step is
    Python's, discarded with the reason; the FMU stays where it was and goes on."""
    h = Host3(fmu3("slider_crank"))
    vr = h.vr["solver.max_steps_per_communication_step"]
    h.fmu.enterInitializationMode(startTime=0.0)
    h.fmu.setInt32([vr], [1])
    h.fmu.exitInitializationMode()
    for _ in range(12):
        assert h.step(H)[0] == OK
    x = h.get("slider.x")
    assert h.step(10 * H)[0] == DISCARD
    assert "solver.max_steps_per_communication_step" in h.last()[2]
    assert h.get("slider.x") == x
    assert h.step(H)[0] == OK
    assert taken_by_wrapper(h) >= 3


def test_every_other_fmi3_call_after_the_wrappers_steps_sees_the_slave_caught_up(fmu3):
    """After steps the wrapper took: an Int32 get, fmi3EnterStepMode (no Event Mode: refused
    by the slave, which then serves its values), Reset (then a run from the start) and
    Terminate (then gets) answer as an instance whose steps went through Python."""
    path = fmu3("n_four_bar_2")
    fast, slow = Host3(path, "fast").init(), Host3(path, "slow").init()
    names = names_of(fast)
    first = [step_both(fast, slow, H, names) for _ in range(30)]
    vr = [fast.vr["solver.max_steps_per_communication_step"]]
    assert fast.fmu.getInt32(vr) == slow.fmu.getInt32(vr)
    assert fast.get(*names) == slow.get(*names) == first[-1]
    for _ in range(30):
        step_both(fast, slow, H, names)
    for h in (fast, slow):
        assert h.status(lambda f: f.enterStepMode()) != OK
        assert "fmi3EnterStepMode" in h.last()[2]
    assert fast.get(*names) == slow.get(*names)
    assert taken_by_wrapper(fast) >= 50
    for h in (fast, slow):
        h.fmu.reset()
        h.t = 0.0
        h.init()
    assert [step_both(fast, slow, H, names) for _ in range(30)] == first
    for _ in range(10):
        step_both(fast, slow, H, names)
    fast.fmu.terminate()
    slow.fmu.terminate()
    assert fast.get(*names) == slow.get(*names)
    assert fast.get("time") == [pytest.approx(0.04)]


@pytest.mark.parametrize("method", ["genalpha", "ali3p"])
def test_fmi3_implicit_steps_are_the_wrappers_and_pythons_values(method, tmp_path):
    """genalpha and ali3p at a fixed step, a torque set before every step (the pendulum
    with its input torque): the wrapper's implicit kind (ckernel/implicit_run.h) takes the
    sets and the fmi3DoSteps, with Python's values, also after a restored state."""
    scene = tmp_path / "pendulum_torque.toml"
    scene.write_text((ROOT / "scenes" / "pendulum_torque.toml").read_text()
                     + f'\n[simulation]\nmethod = "{method}"\nstep = 1e-3\n')
    path = build_fmu(scene, tmp_path / "implicit.fmu", fmi_version=3)
    fast, slow = Host3(path, "fast").init(), Host3(path, "slow").init()
    names = names_of(fast)
    for k in range(200):
        for h in (fast, slow):
            h.set(**{"drive.torque": 2.0 * np.sin(0.05 * k)})
        step_both(fast, slow, H, names)
    through_python(fast)
    assert taken_by_wrapper(slow) == 0 and taken_by_wrapper(fast) >= 195
    replays(fast, path, 5, names, "drive.torque", lambda t: 2.0 * np.sin(50.0 * t))
