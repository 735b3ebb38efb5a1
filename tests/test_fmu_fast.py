"""The FMU's fast path: the shipped C kernel (and the numpy kernel, logged, without it),
and fmi2GetReal served by the wrapper after a step, which must never serve a stale value:
every other call reads through Python again (runtime/real_cache.py)."""

from __future__ import annotations

import ctypes
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mbdfmu  # noqa: E402
from mbdfmu.equations import ckernel  # noqa: E402
from mbdfmu.fmu_build.scene_fmu import KERNEL_FILE  # noqa: E402
from fmu_models.harness import DISCARD, ERROR, OK, get_state  # noqa: E402
from fmu_models.scenes import SCENES, scene_fmu, scene_host  # noqa: E402,F401

pytestmark = pytest.mark.skipif(not ckernel.available(), reason="no C compiler for the kernel")
H = 1e-3


def without_kernel(path: Path, target: Path) -> Path:
    """A copy of the FMU without its compiled kernel (as built where no compiler was)."""
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(target, "w") as dst:
        for item in src.infolist():
            if item.filename != f"resources/{KERNEL_FILE}":
                dst.writestr(item, src.read(item.filename))
    return target


def run(h, names, steps, force=None):
    out = []
    for k in range(steps):
        if force is not None:
            assert h.set_real([h.vr[force]], [np.sin(20 * h.t)]) == OK
        assert h.step(H) == OK, h.messages[-3:]
        out.append(h.real(*names))
    return np.array(out)


def test_the_fmu_ships_its_kernel_and_runs_it(scene_fmu):
    with zipfile.ZipFile(scene_fmu("slider_force")) as z:
        assert f"resources/{KERNEL_FILE}" in z.namelist()


def test_without_its_kernel_the_fmu_runs_numpy_and_says_so(scene_fmu, scene_host, tmp_path):
    path = without_kernel(scene_fmu("slider_force"), tmp_path / "plain.fmu")
    plain, fast = scene_host(path, "plain").init(), scene_host(scene_fmu("slider_force"), "c").init()
    assert any("the numpy kernel runs" in m for _, _, m in plain.messages)
    assert not any("numpy kernel" in m for _, _, m in fast.messages)
    names = plain.outputs
    got, expected = run(fast, names, 30, "push.fx"), run(plain, names, 30, "push.fx")
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)


def test_get_real_after_a_step_never_serves_a_stale_value(scene_fmu, scene_host):
    """Values served without Python equal Python's after steps, sets, state restores and
    a reset; a get that names a non-Real variable is refused as before."""
    h = scene_host(scene_fmu("slider_force")).init()
    x = [h.vr["slider.x"]]
    first = run(h, ["slider.x"], 5, "push.fx")
    state = get_state(h)
    later = run(h, ["slider.x"], 5, "push.fx")
    assert later[-1, 0] != first[-1, 0]
    assert h.status("fmi2SetFMUstate", state) == OK
    assert h.get_real(*x) == (OK, [first[-1, 0]])          # the restored state's value
    assert h.set_real([h.vr["push.fx"]], [0.5]) == OK
    assert h.get_real(h.vr["push.fx"]) == (OK, [0.5])      # set values read back at once
    assert h.get_real(10**6)[0] != OK                      # unknown reference: an error...
    assert "fmi2GetReal" in h.messages[-1][2]              # ...said by the runtime


def test_a_discarded_step_leaves_values_that_are_read_through_python(scene_fmu, scene_host):
    h = scene_host(scene_fmu("slider_force"))
    # 5: the slider starts at rest with no force, so y' = 0 and the first step is 1e-6 s
    # (Hairer's starting rule), growing tenfold a step: 4 steps reach the first 1 ms
    assert h.set_int("solver.max_steps_per_communication_step", 5) == OK
    before = run(h.init(), ["slider.x"], 3, "push.fx")
    assert h.status("fmi2DoStep", h.t, 1e6, 1) == DISCARD
    assert h.real("slider.x") == [before[-1, 0]]


def test_steps_inside_the_solvers_step_are_the_wrappers_and_pythons_values(scene_fmu, scene_host):
    """P2 N = 2 (dop853p: its steps are far longer than 1 ms; no drivers, no inputs): the
    wrapper takes the communication steps that end inside the solver's last step by itself
    (runtime/real_cache.py FastSteps, ckernel/dense.h) and says how many when the slave
    catches up; every value it serves is bit for bit the one Python computes when the same
    steps go through it (fmi2SetDebugLogging after each step sends the next one there)."""
    path = scene_fmu("n_four_bar_2")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    names = fast.outputs
    got, expected = [], []
    for _ in range(400):
        assert fast.step(H) == OK and slow.step(H) == OK, (fast.messages[-3:], slow.messages[-3:])
        got.append(fast.real(*names))
        expected.append(slow.real(*names))
        assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    np.testing.assert_array_equal(np.array(got), np.array(expected))
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK    # the slave catches up

    def taken(h):
        return sum(int(m.split(": ")[1].split()[0]) for _, _, m in h.messages
                   if "taken by the wrapper" in m)
    assert taken(slow) == 0
    # the integrator's steps are tens of ms long: all but about one doStep in each
    assert taken(fast) > 300
    # and the state it caught up with is the one it served
    assert fast.real(*names) == got[-1]


def taken_by_wrapper(h) -> int:
    """Communication steps the wrapper took without Python, as the slave logs them."""
    return sum(int(m.split(": ")[1].split()[0]) for _, _, m in h.messages
               if "taken by the wrapper" in m)


def step_both(fast, slow, step: float, names) -> list[float]:
    """One doStep of both instances, ``slow`` sent through Python for its next call
    (fmi2SetDebugLogging after each step): ``names``' values, the same bit for bit."""
    assert fast.step(step) == OK and slow.step(step) == OK, (fast.messages[-3:],
                                                             slow.messages[-3:])
    values = fast.real(*names)
    assert values == slow.real(*names)
    assert slow.status("fmi2SetDebugLogging", True, 0, None) == OK
    return values


LINEAR_MOTOR = 'motion = { type = "linear", start = 0.0, rate = 314.1592653589793 }'
HARMONIC_MOTOR = 'motion = { type = "harmonic", offset = 0.0, amplitude = 0.3, frequency = 40.0 }'
# the drive's closed form: the crank's angle at t
MOTOR_ANGLE = {"linear": lambda t: 314.1592653589793 * t,
               "harmonic": lambda t: 0.3 * np.sin(2 * np.pi * 40.0 * t)}


@pytest.mark.parametrize("motor", ["linear", "harmonic"])
def test_rk4p_steps_with_a_driver_are_the_wrappers_and_pythons_values(
        motor, scene_fmu, scene_host, tmp_path):
    """The slider-crank (auto->rk4p; the motor's linear or harmonic motion evaluated in C,
    ckernel/fixed.h): the wrapper takes its doSteps (1 ms, some 3 ms) by itself, all but
    the first (Python's, after which the slave arms it), rk4p's step-doubling checks
    included (after SPOT_CHECK_EVERY steps, then at intervals that double while the
    checks agree), and every value it serves is bit for bit the one Python computes when
    each step goes through it; a state taken after fast steps restores to the same
    values."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    from mbdfmu.integrators.stated_accuracy import SPOT_CHECK_EVERY
    path = scene_fmu("slider_crank")
    if motor == "harmonic":
        text = (SCENES / "slider_crank.toml").read_text()
        assert LINEAR_MOTOR in text
        scene = tmp_path / "slider_crank_harmonic.toml"
        scene.write_text(text.replace(LINEAR_MOTOR, HARMONIC_MOTOR))
        path = build_fmu(scene, tmp_path / "harmonic.fmu")
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    names = fast.outputs + ["crank.x", "rod.alpha"]
    steps = 16 * SPOT_CHECK_EVERY + 7
    got = []
    for k in range(steps):
        got.append(step_both(fast, slow, 3 * H if k % 10 == 9 else H, names))   # 3 rk4p steps
    np.testing.assert_allclose(fast.real("crank.phi")[0], MOTOR_ANGLE[motor](fast.t),
                               rtol=1e-9, atol=1e-12)
    state, t = get_state(fast), fast.t             # the slave catches up first
    assert taken_by_wrapper(slow) == 0
    assert taken_by_wrapper(fast) == steps - 1
    assert fast.real(*names) == got[-1]
    more = run(fast, names, 5)
    assert fast.status("fmi2SetFMUstate", state) == OK
    fast.t = t
    assert fast.real(*names) == got[-1]
    np.testing.assert_array_equal(run(fast, names, 5), more)


CRANE = Path(__file__).resolve().parents[1] / "scenarios" / "hydraulic_crane" / "crane.toml"
CRANE_METHOD = 'method = "dop853p"'


@pytest.fixture(scope="module")
def crane_fmu(tmp_path_factory):
    """The hydraulic crane's mechanism (dop853p, its cylinder force an input)."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    return build_fmu(CRANE, tmp_path_factory.mktemp("crane") / "crane.fmu")


@pytest.fixture(scope="module", params=["dop853p", "auto", "rk4p"])
def crane_method_fmu(request, crane_fmu, tmp_path_factory):
    """The crane's mechanism with its scene's method, with auto (it picks dop853p and
    watches it) and with rk4p: (method, FMU)."""
    from mbdfmu.fmu_build.scene_fmu import build_fmu
    if request.param == "dop853p":
        return request.param, crane_fmu
    text = CRANE.read_text()
    assert CRANE_METHOD in text
    folder = tmp_path_factory.mktemp(f"crane_{request.param}")
    scene = folder / "crane.toml"
    scene.write_text(text.replace(CRANE_METHOD, f'method = "{request.param}"'))
    return request.param, build_fmu(scene, folder / "crane.fmu")


def actuator(t: float) -> float:
    """A cylinder force about holding the boom, swinging (N)."""
    return 8420.0 * (1.0 + 0.05 * np.sin(2.0 * np.pi * t))


def test_steps_after_an_input_set_are_the_wrappers_and_pythons_values(crane_method_fmu,
                                                                     scene_host):
    """The crane with its cylinder force set by the master before every step: the wrapper
    takes fmi2SetReal of the force and the step by itself (the restart after an input
    change, then dop853p's step landing on the communication point with its controller,
    ckernel/adaptive.h, also under auto, whose stiffness test it checks; or rk4p's steps,
    ckernel/fixed.h), and every value is bit for bit Python's when each call goes through
    it. A get between the set and the step (the accelerations follow the new force) and a
    state saved there go through Python and agree too."""
    method, crane_fmu = crane_method_fmu
    fast, slow = scene_host(crane_fmu, "fast").init(), scene_host(crane_fmu, "slow").init()
    force = [fast.vr["cylinder.actuator"]]
    names = fast.outputs + [n for n in fast.vr if n.endswith((".alpha", ".ax", ".phi"))]
    got = []
    for k in range(200):
        last = actuator(fast.t)
        for h in (fast, slow):
            assert h.set_real(force, [last]) == OK
        if k == 150:              # read between the set and the step: through Python
            assert fast.real(*names) == slow.real(*names)
        got.append(step_both(fast, slow, 20 * H if k % 10 == 9 else H, names))
    assert fast.real("cylinder.actuator") == [last]
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK       # catches up
    assert taken_by_wrapper(slow) == 0
    # rk4p: 580 steps, its step-doubling checks among them taken by the wrapper too
    assert taken_by_wrapper(fast) >= 190
    # states taken after the wrapper's steps go on as Python's, restored or not
    state_fast, state_slow, t = get_state(fast), get_state(slow), fast.t
    assert fast.real(*names) == got[-1]
    ahead = run(fast, names, 5, "cylinder.actuator")
    np.testing.assert_array_equal(ahead, run(slow, names, 5, "cylinder.actuator"))
    assert fast.status("fmi2SetFMUstate", state_fast) == OK and \
        slow.status("fmi2SetFMUstate", state_slow) == OK
    fast.t = slow.t = t
    np.testing.assert_array_equal(run(fast, names, 5, "cylinder.actuator"), ahead)
    np.testing.assert_array_equal(run(slow, names, 5, "cylinder.actuator"), ahead)


def test_the_wrappers_long_steps_carry_the_step_controllers_memory(crane_fmu, scene_host):
    """Communication steps of 0.4 s after a force set, each five to nine dop853p steps:
    the PI controller's memory (the last kept step's error) goes from one doStep to the
    next in the wrapper as in Python, so the values stay Python's bit for bit. (At 0.1 s
    every step is cut to land, and a cut step leaves the memory as it was.)"""
    fast, slow = scene_host(crane_fmu, "fast").init(), scene_host(crane_fmu, "slow").init()
    force, names = [fast.vr["cylinder.actuator"]], fast.outputs
    for k in range(5):
        for h in (fast, slow):
            assert h.set_real(force, [actuator(fast.t)]) == OK
        step_both(fast, slow, 0.4, names)
        if k == 2:      # the slave takes the memory back from the wrapper, and on from it
            assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK       # catches up
    assert taken_by_wrapper(fast) >= 3 and taken_by_wrapper(slow) == 0


def test_a_get_between_a_set_and_the_step_is_the_wrappers_where_the_set_changes_nothing(
        crane_method_fmu, scene_host):
    """After the wrapper took fmi2SetReal of the crane's force, a get of values the force
    leaves as they are (the body states, the cylinder's length and rate, a parameter, the
    force itself) is the wrapper's: the slave never catches up between the steps (one
    catch-up in 40 steps, against one a step when such gets went through Python). A get
    naming an acceleration goes through Python. Both are Python's values bit for bit."""
    method, crane_fmu = crane_method_fmu
    fast, slow = scene_host(crane_fmu, "fast").init(), scene_host(crane_fmu, "slow").init()
    force = [fast.vr["cylinder.actuator"]]
    states = [n for n in fast.vr if n.endswith((".x", ".y", ".phi", ".vx", ".vy", ".omega"))]
    kept = fast.outputs + states + ["cylinder.actuator", "cylinder.damping"]
    for k in range(40):
        for h in (fast, slow):
            assert h.set_real(force, [actuator(h.t)]) == OK
        assert fast.real(*kept) == slow.real(*kept)
        step_both(fast, slow, H, kept)
    assert fast.status("fmi2SetDebugLogging", True, 0, None) == OK       # catches up
    catch_ups = [m for _, _, m in fast.messages if "taken by the wrapper" in m]
    assert len(catch_ups) == 1 and taken_by_wrapper(fast) >= 39, catch_ups
    for h in (fast, slow):
        h.step(H)
        assert h.set_real(force, [actuator(h.t)]) == OK
    accelerations = [n for n in fast.vr if n.endswith(".alpha")]
    assert fast.real(*accelerations) == slow.real(*accelerations)


@pytest.mark.parametrize("stem, inputs", [("crane", ("cylinder.actuator",)),
                                          ("slider_force", ("push.fx", "push.fy")),
                                          ("pendulum_torque", ("drive.torque",))])
def test_every_value_a_get_reads_after_a_set_in_the_wrapper_is_pythons(
        scene_fmu, crane_fmu, scene_host, stem, inputs):
    """Every Real variable of scenes with force inputs, read one at a time between a set
    the wrapper took and the next step (those the set leaves as they are from the wrapper,
    the others through Python), is what an instance sent through Python at every call
    reads, bit for bit: no value the inputs change is served as it was before the set (a
    mask that keeps every value fails here)."""
    from fmpy import read_model_description
    path = crane_fmu if stem == "crane" else scene_fmu(stem)
    fast, slow = scene_host(path, "fast").init(), scene_host(path, "slow").init()
    names = [v.name for v in read_model_description(path).modelVariables if v.type == "Real"]
    for k in range(6):
        for h in (fast, slow):
            assert h.set_real([h.vr[n] for n in inputs],
                              [1e3 * np.sin(20 * h.t) + j for j in range(len(inputs))]) == OK
        for name in names:
            assert fast.real(name) == slow.real(name), (k, name)
        step_both(fast, slow, H, fast.outputs)


def test_steps_beyond_the_work_limit_are_discarded_by_python_not_taken_by_the_wrapper(
        scene_fmu, crane_fmu, scene_host):
    """The wrapper's steps respect solver.max_steps_per_communication_step: a 1 ms step
    (one rk4p step; one landing dop853p step) is its own, a 10 ms one needs more steps
    than allowed, so Python takes it and discards it, saying why; the FMU stays where it
    was and a shorter step goes on."""
    for path, name, force in ((scene_fmu("slider_crank"), "slider.x", None),
                              (crane_fmu, "boom.phi", "cylinder.actuator")):
        h = scene_host(path)
        assert h.set_int("solver.max_steps_per_communication_step", 1) == OK
        before = run(h.init(), [name], 12, force)
        if force is not None:
            assert h.set_real([h.vr[force]], [actuator(h.t)]) == OK
        assert h.status("fmi2DoStep", h.t, 10 * H, 1) == DISCARD
        assert "solver.max_steps_per_communication_step" in h.messages[-1][2]
        assert h.real(name) == [before[-1, 0]]
        assert h.step(H) == OK
        assert taken_by_wrapper(h) >= 3


def test_a_set_the_wrapper_cannot_take_is_pythons_and_says_why(crane_fmu, scene_host):
    """After the wrapper's steps and a force it took: a non-finite force is fmi2Discard and
    a fixed parameter fmi2Error, said by Python as before; the valid values are applied."""
    h = scene_host(crane_fmu).init()
    vr = h.vr["cylinder.actuator"]
    run(h, ["boom.phi"], 5, "cylinder.actuator")
    assert h.set_real([vr], [9000.0]) == OK
    assert h.set_real([vr], [float("nan")]) == DISCARD
    assert "finite" in h.messages[-1][2]
    assert h.real("cylinder.actuator") == [9000.0]
    assert h.set_real([vr, h.vr["boom.mass"]], [9500.0, 1.0]) == ERROR
    assert "boom.mass" in h.messages[-1][2]
    assert h.real("cylinder.actuator") == [9500.0]
    assert taken_by_wrapper(h) >= 3


@pytest.mark.parametrize("below", [False, True])
def test_autos_stiffness_test_in_c_is_pythons(below, tmp_path):
    """Under auto the wrapper's dop853p steps check auto's stiffness test (Hairer's h
    |lambda|, auto_watch.stiffness) in C (adaptive.h): a step above the limit goes back to
    Python, whose watcher counts it. Both compute it with the same C function: with the
    limit at the h |lambda| Python computes for the same step, the wrapper takes the step
    (and reaches Python's state bit for bit); one double below, it hands it back."""
    from mbdfmu import fast_steps
    from mbdfmu.integrators.auto_watch import STIFF_HLAMBDA, stiffness
    scene = tmp_path / "crane.toml"
    scene.write_text(CRANE.read_text().replace(CRANE_METHOD, 'method = "auto"'))

    def crane():
        sim = mbdfmu.Simulation(mbdfmu.load_scene(scene), kernel="c")
        for k in range(5):
            sim.set_input("cylinder.actuator", actuator(k * H))
            sim.advance((k + 1) * H)
        return sim

    python, wrapper = crane(), crane()
    steps = python.integrator.stats.nsteps
    python.advance(6 * H)                  # the force held: one landing step
    assert python.integrator.stats.nsteps == steps + 1 and python.method_name == "auto->dop853p"
    h_lambda = stiffness(python.integrator.current)
    assert 0.0 < h_lambda < STIFF_HLAMBDA
    kind, kernel, (run, table), _ = fast_steps.fast_steps_ahead(wrapper, None, 1e-9)
    assert kind == "prk" and run["stiff_limit"] == STIFF_HLAMBDA    # auto's watch, in C
    run["stiff_limit"] = np.nextafter(h_lambda, 0.0) if below else h_lambda
    none = np.zeros(0, dtype=np.int64)
    step, model, context, _ = kernel.arm_prk_steps(run, table, (none, none), none, none)
    call = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                            ctypes.c_double, ctypes.c_void_p)(step)
    values = np.zeros(1)
    assert (call(model, context, 5 * H, H, values.ctypes.data) == 0) == (not below)
    moved, _, _ = fast_steps.catch_up(wrapper, (none, none))
    assert moved == (not below)
    if not below:
        assert wrapper.t == python.t and np.array_equal(wrapper.q, python.q) and \
            np.array_equal(wrapper.qd, python.qd)
