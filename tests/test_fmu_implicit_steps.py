"""An FMU whose steps are genalpha's or ali3p's controlled steps (auto's stiff scenes, or
the scene's own step_control = "adaptive"): its C wrapper takes each 1 ms communication
step as one run of them (ckernel/implicit_run.h, integrators/implicit_runs.py), landing on
the communication point. References: the same FMU sent through Python at every doStep
(fmi2SetDebugLogging after each), equal bit for bit after every step, and the rigid
pendulum's elliptic solution (bench/closed_forms.py) that a 1e10 N/m spring follows to
about 3 m g / k (its bob spinning freely at 50 rad/s); never the wrapper's own output."""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from mbdfmu.bench import closed_forms  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import build_fmu  # noqa: E402
from mbdfmu.scenes import variants  # noqa: E402
from fmu_models.harness import OK, get_state, serialize  # noqa: E402
from fmu_models.scenes import scene_host  # noqa: E402,F401
from test_fmu_dense_run import lockstep, taken_by_wrapper  # noqa: E402

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
SCENES = Path(__file__).resolve().parents[1] / "scenes"
H = 1e-3

# the shipped stiff spring with its bob spinning freely (its angle wraps: the steps'
# periodic angles) and the spring's outputs published
SPRING = (SCENES / "stiff_spring.toml").read_text().replace(
    "gravity = [0.0, -9.81]", 'gravity = [0.0, -9.81]\noutputs = ["bob.*", "rod.*"]').replace(
    "angular_velocity = 0.0", "angular_velocity = 50.0")
assert "angular_velocity = 50.0" in SPRING and "outputs = " in SPRING
# the spring stretched by 0.1 mm at the start and damped (test_auto_watch.py's): auto
# starts with dop853p, which resolves the ringing, then switches to genalpha at its fixed
# step once stability holds dop853p's steps
STRETCHED = SPRING.replace("position = [1.0, 0.0]", "position = [1.0001, 0.0]").replace(
    "damping = 0.0", "damping = 1000.0")
def adaptive(stem: str, method: str) -> str:
    """A shipped scene with ``method`` under step control."""
    text = (SCENES / f"{stem}.toml").read_text()
    assert "[simulation]" not in text
    return text + f'\n[simulation]\nmethod = "{method}"\n[simulation.options]\n' \
                  'step_control = "adaptive"\n'


def fixed(stem: str, method: str, step: float) -> str:
    """A shipped scene with ``method`` at a fixed ``step``."""
    text = (SCENES / f"{stem}.toml").read_text()
    assert "[simulation]" not in text
    return text + f'\n[simulation]\nmethod = "{method}"\nstep = {step!r}\n'


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("implicit_fmus")
    hooked = variants.hooked(SPRING)     # its spring between the hook's pin and the bob
    sources = {"spring": SPRING, "pushed": variants.pushed(SPRING), "hooked": hooked,
               "stretched": STRETCHED,
               "crank_genalpha": adaptive("slider_crank", "genalpha"),
               "crank_ali3p": adaptive("slider_crank", "ali3p"),
               "p2_genalpha": fixed("n_four_bar_2", "genalpha", 1e-3),
               "p2_ali3p": fixed("n_four_bar_2", "ali3p", 5e-4),
               "crank_fixed": fixed("slider_crank", "genalpha", 2.5e-4),
               "torque_fixed": fixed("pendulum_torque", "ali3p", 1e-3),
               "loop_fixed": fixed("pendulum", "genalpha", 1e-3).replace(
                   "velocity = [0.0, 0.0]\nangular_velocity = 0.0",
                   "velocity = [0.0, 12.0]\nangular_velocity = 12.0")}
    assert "angular_velocity = 12.0" in sources["loop_fixed"]
    built = {}
    for name, text in sources.items():
        (folder / f"{name}.toml").write_text(text)
        built[name] = build_fmu(folder / f"{name}.toml", folder / f"{name}.fmu")
    return built


def hosts(scene_host, path, max_steps: int | None = None):
    made = tuple(scene_host(path, name) for name in ("fast", "slow"))
    for host in made:
        if max_steps is not None:
            assert host.set_int("solver.max_steps_per_communication_step", max_steps) == OK
        host.init()
    return made


def same_state(fast, slow) -> bool:
    """The whole state of the two instances, serialized, is the same to the byte: the
    integrator's (its kept matrix, the controller's step, the energy audit, the stated
    accuracy's estimate) and every counter of the run."""
    return serialize(fast, get_state(fast)) == serialize(slow, get_state(slow))


def wrapper_steps(host) -> int:
    """The steps the wrapper took, once the slave caught up (any other call makes it)."""
    assert host.status("fmi2SetDebugLogging", True, 0, None) == OK
    return taken_by_wrapper(host)


def test_a_stiff_spring_under_auto_steps_in_the_wrapper_as_in_python(fmus, scene_host):
    fast, slow = hosts(scene_host, fmus["spring"])
    times, xs, ys = [], [], []
    for k in range(300):
        lockstep(fast, slow, 1)
        times.append((k + 1) * H)
        x, y = fast.real("bob.x", "bob.y")
        xs.append(x)
        ys.append(y)
    assert wrapper_steps(fast) >= 290 and wrapper_steps(slow) == 0
    assert same_state(fast, slow)
    exact = closed_forms.pendulum(np.array(times), J=1e-6)
    error = float(np.max(np.hypot(np.array(xs) - exact["x"], np.array(ys) - exact["y"])))
    assert error < 1e-6, error          # the default tolerance: 1e-6 m (measured 4e-7)


@pytest.mark.parametrize("which", ["crank_genalpha", "crank_ali3p"])
def test_the_driven_slider_crank_under_step_control(which, fmus, scene_host):
    """genalpha (the banded Schur complement, the kernel's velocity projection) and ali3p
    (a dense LU where the slider's line couples bodies), the motor's motion evaluated at
    every step's end."""
    fast, slow = hosts(scene_host, fmus[which])
    lockstep(fast, slow, 200)
    assert wrapper_steps(fast) >= 190
    assert same_state(fast, slow)


@pytest.mark.parametrize("which, every, along", [("pushed", 1, 0.0), ("pushed", 7, 0.0),
                                                 ("hooked", 1, 0.0), ("pushed", 7, 3.0)])
def test_force_inputs_set_before_steps_are_taken_by_the_wrapper(which, every, along, fmus,
                                                                scene_host):
    """fmi2SetReal of the push, before every step or every 7th: the wrapper takes the set
    and restarts as Python does (the projection, eq. (14), a fresh iteration matrix).
    "hooked": the spring hangs from a pinned body, so the restart projects onto its joint.
    ``along``: the push has a part along the spring too, which rings its 1e10 N/m mode: the
    step control rejects steps over the ringing and filters the next attempt's error twice
    (implicit_control.py), in C as in Python."""
    fast, slow = hosts(scene_host, fmus[which])
    vrs = (ctypes.c_uint * 2)(fast.vr["push.fx"], fast.vr["push.fy"])
    for k in range(140):
        if k % every == 0:
            values = (ctypes.c_double * 2)(along * np.sin(0.1 * k), -2.0 + np.sin(0.1 * k))
            for host in (fast, slow):
                assert host.status("fmi2SetReal", vrs, 2, values) == OK
        lockstep(fast, slow, 1)
    assert wrapper_steps(fast) >= 135
    assert same_state(fast, slow)


@pytest.mark.parametrize("which", ["p2_genalpha", "p2_ali3p", "crank_fixed", "loop_fixed"])
def test_fixed_steps_are_taken_by_the_wrapper_as_in_python(which, fmus, scene_host):
    """genalpha and ali3p at the scene's fixed step: the grid of steps, the energy check,
    the stated accuracy's estimate and its step-doubling checks in C (one, two and four
    steps a doStep: the slider-crank's checks fall inside doSteps; the looping pendulum's
    angle wraps, which the checks' differences must not see)."""
    fast, slow = hosts(scene_host, fmus[which])
    lockstep(fast, slow, 400)
    assert wrapper_steps(fast) == 399       # all but the first, which arms them
    assert same_state(fast, slow)


def test_auto_switching_to_genalpha_for_stiffness_goes_on_in_the_wrapper(fmus, scene_host):
    """After auto's switch from dop853p (its fixed step; retried at half the step where the
    stated accuracy asks, test_auto_watch.py), the steps are the wrapper's."""
    fast, slow = hosts(scene_host, fmus["stretched"])
    lockstep(fast, slow, 300)
    assert same_state(fast, slow)
    assert any("auto switched from dop853p to genalpha" in m for _, _, m in slow.messages)
    assert wrapper_steps(fast) >= 280       # all but the first few, which dop853p took


def test_a_torque_set_before_every_fixed_step(fmus, scene_host):
    fast, slow = hosts(scene_host, fmus["torque_fixed"])
    vr = (ctypes.c_uint * 1)(fast.vr["drive.torque"])
    for k in range(300):
        value = (ctypes.c_double * 1)(2.0 * np.sin(0.05 * k))
        for host in (fast, slow):
            assert host.status("fmi2SetReal", vr, 1, value) == OK
        lockstep(fast, slow, 1)
    assert wrapper_steps(fast) >= 295
    assert same_state(fast, slow)


def test_a_work_limit_hands_the_step_to_python_which_says_why(fmus, scene_host):
    fast, slow = hosts(scene_host, fmus["spring"], max_steps=3)
    lockstep(fast, slow, 20)
    assert wrapper_steps(fast) >= 19
    codes = [host.step(0.05) for host in (fast, slow)]
    assert codes[0] == codes[1] != OK
    reasons = [[m for _, _, m in host.messages if "internal steps" in m][-1:]
               for host in (fast, slow)]
    assert reasons[0] == reasons[1] != []
    lockstep(fast, slow, 5)     # both from where the refused step began


def test_a_state_taken_after_the_wrappers_steps_goes_on_bit_for_bit(fmus, scene_host):
    """The kept iteration matrix, the controller's step and the energy audit are the
    wrapper's until the slave catches up (fmi2GetFMUstate makes it)."""
    fast, slow = hosts(scene_host, fmus["spring"])
    lockstep(fast, slow, 50)
    state, t = get_state(fast), fast.t
    lockstep(fast, slow, 50)
    first = fast.real(*fast.outputs)
    assert fast.status("fmi2SetFMUstate", state) == OK
    fast.t = t
    for _ in range(50):
        assert fast.step(H) == OK
    assert fast.real(*fast.outputs) == first
