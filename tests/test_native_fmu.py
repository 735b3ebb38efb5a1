"""The native FMU runtime (fmu_build/native, fmu_build/runtime) against real hosts.

The toy FMU (tests/fmu_models: a damped mass-spring integrated exactly per step) is built
once; every result is compared with the closed-form solution or with another host, and
every misuse of the FMI API listed in the reliability findings is replayed through fmpy's
low-level FMU2Slave, asserting the status, the logged reason and what still works.
"""

from __future__ import annotations

import ctypes
import math
import pickle
import random
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:       # this checkout's fmu_build, not an installed copy
    sys.path.insert(0, str(ROOT))

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE,  # noqa: E402
                       fmi2CallbackFreeMemoryTYPE, fmi2CallbackFunctions,
                       fmi2CallbackLoggerTYPE, fmi2FMUstate)
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_build.runtime import state_format  # noqa: E402
from fmu_models import hosts  # noqa: E402
from fmu_models.toy import F, IDENTIFIER, K, M, VR, X0, build_toy, closed_form  # noqa: E402

OK, WARNING, DISCARD, ERROR, FATAL = range(5)
H = 0.01                      # communication step of the runs (s)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("native")


@pytest.fixture(scope="module")
def toy(workdir) -> Path:
    return build_toy(workdir / f"{IDENTIFIER}.fmu", cache_dir=workdir / "cache")


@pytest.fixture(scope="module")
def unzipped(toy) -> tuple[str, object]:
    return extract(toy), read_model_description(toy)


class Host:
    """One instance through fmpy's FMU2Slave, logging on, every message kept."""

    def __init__(self, unzipped, name="a", logging_on=True):
        directory, md = unzipped
        self.messages: list[tuple[int, str, str]] = []
        self._keep = self._callbacks()
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=directory, modelIdentifier=IDENTIFIER,
                             instanceName=name)
        self.fmu.instantiate(callbacks=self._keep, loggingOn=logging_on)
        self.t = 0.0

    def _callbacks(self):
        def log(env, name, status, category, message):
            self.messages.append((status, category.decode(), message.decode()))
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(log)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        return callbacks

    def status(self, function, *args) -> int:
        """Call a raw fmi2 function of the instance; its status (fmpy raises above Warning)."""
        try:
            getattr(self.fmu, function)(self.fmu.component, *args)
            return OK
        except FMICallException as exc:
            return exc.status

    def init(self):
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        return self

    def step(self, h=H) -> int:
        code = self.status("fmi2DoStep", self.t, h, 1)
        if code == OK:
            self.t += h
        return code

    def get_real(self, *vrs) -> tuple[int, list[float]]:
        values = (ctypes.c_double * len(vrs))()
        code = self.status("fmi2GetReal", (ctypes.c_uint * len(vrs))(*vrs), len(vrs), values)
        return code, list(values)

    def set_real(self, vrs, values) -> int:
        return self.status("fmi2SetReal", (ctypes.c_uint * len(vrs))(*vrs), len(vrs),
                           (ctypes.c_double * len(vrs))(*values))

    def xs(self, n) -> list[float]:
        """x after each of n steps."""
        out = []
        for _ in range(n):
            assert self.step() == OK, self.messages[-3:]
            out.append(self.get_real(VR["x"])[1][0])
        return out

    def last(self) -> tuple[int, str, str]:
        return self.messages[-1]

    def free(self):
        self.fmu.freeInstance()


@pytest.fixture
def host(unzipped):
    made = []

    def make(name="a", logging_on=True):
        made.append(Host(unzipped, name, logging_on))
        return made[-1]
    yield make
    for h in made:
        h.free()


def assert_closed_form(times, xs, vs, force=F):
    for t, x, v in zip(times, xs, vs):
        x_ref, v_ref = closed_form(t, force=force)
        assert abs(x - x_ref) <= 1e-9 and abs(v - v_ref) <= 1e-9, (t, x, x_ref, v, v_ref)


# ------------------------------------------------------------------ model description, hosts

def test_model_description_passes_fmpy_validate(toy):
    assert validate_fmu(str(toy)) == []


@pytest.mark.skipif(not hosts.CHECKER.exists(), reason="the Compliance Checker is not in ../shared")
def test_compliance_checker_from_a_clean_environment_matches_the_closed_form(toy, tmp_path):
    run = hosts.run_checker(toy, tmp_path, stop=1.0, h=H)
    assert run.returncode == 0, run.stdout + run.stderr
    report = run.stdout + run.stderr
    assert "0 Warning(s)" in report and "0 Error(s)" in report, report
    data = np.genfromtxt(tmp_path / "out.csv", delimiter=",", names=True)
    assert len(data) == 101 and data["time"][-1] == pytest.approx(1.0)
    assert_closed_form(data["time"], data["x"], data["v"])


def test_fmpy_simulate_matches_the_closed_form(toy):
    result = simulate_fmu(toy, stop_time=1.0, output_interval=H)
    assert len(result) == 101
    assert_closed_form(result["time"], result["x"], result["v"])


def test_libcosim_matches_the_closed_form(toy):
    pytest.importorskip("libcosimpy")
    run = hosts.run_python(hosts.LIBCOSIM_RUN, toy, 100, H)
    assert run.returncode == 0, run.stderr[-2000:]
    assert abs(hosts.result(run.stdout) - closed_form(1.0)[0]) <= 1e-9


@pytest.mark.parametrize("kind", ["fmpy", "libcosim", "checker"])
def test_fresh_processes_load_step_free_and_exit_cleanly(toy, tmp_path, kind):
    """The exit crash of pythonfmu FMUs (SIGSEGV / abort after numpy) must not happen."""
    runs = 10
    for i in range(runs):
        if kind == "checker":
            if not hosts.CHECKER.exists():
                pytest.skip("the Compliance Checker is not in ../shared")
            (tmp_path / str(i)).mkdir()
            run = hosts.run_checker(toy, tmp_path / str(i), stop=0.1, h=H)
        else:
            if kind == "libcosim":
                pytest.importorskip("libcosimpy")
            script = hosts.FMPY_RUN if kind == "fmpy" else hosts.LIBCOSIM_RUN
            run = hosts.run_python(script, toy, 10, H)
        assert run.returncode == 0, (i, run.returncode, run.stderr[-2000:])


# ------------------------------------------------------------------ hosts without Python

@pytest.fixture(scope="module")
def c_host(workdir) -> Path:
    if not shutil.which("gcc"):
        pytest.skip("gcc is needed to build the C host")
    return hosts.compile_host(workdir)


def run_c_host(c_host, fmus, env_extra=None, steps=100):
    import subprocess
    args = [str(c_host), str(steps), repr(H)]
    for directory, md in fmus:
        args += [directory, md.coSimulation.modelIdentifier, md.guid]
    return subprocess.run(args, capture_output=True, text=True, timeout=120,
                          env=hosts.clean_env(Path(fmus[0][0]), **(env_extra or {})))


def test_a_c_host_without_libpython_runs_two_instances(c_host, unzipped):
    run = run_c_host(c_host, [unzipped])
    assert run.returncode == 0, run.stdout + run.stderr
    xs = [float(line.split()[1]) for line in run.stdout.splitlines() if line.startswith("x ")]
    assert len(xs) == 2 and all(abs(x - closed_form(1.0)[0]) <= 1e-9 for x in xs)


def test_two_different_fmus_run_side_by_side_in_a_c_host(c_host, unzipped, workdir):
    """Different model modules and GUIDs in one interpreter do not clash."""
    source = (Path(__file__).parent / "fmu_models" / "mass_spring.py").read_text()
    variant = source.replace('"""Damped mass-spring (SI', '"""A second FMU: damped mass-spring (SI')
    other = build_toy(workdir / "Variant.fmu", cache_dir=workdir / "cache", source=variant)
    other_unzipped = (extract(other), read_model_description(other))
    assert other_unzipped[1].guid != unzipped[1].guid
    run = run_c_host(c_host, [unzipped, other_unzipped])
    assert run.returncode == 0, run.stdout + run.stderr
    xs = [float(line.split()[1]) for line in run.stdout.splitlines() if line.startswith("x ")]
    assert len(xs) == 4 and all(abs(x - closed_form(1.0)[0]) <= 1e-9 for x in xs)


def test_a_missing_python_library_fails_instantiate_with_one_clear_line(c_host, unzipped):
    run = run_c_host(c_host, [unzipped], {"MBDFMU_PYTHON_LIBRARY": "/nonexistent/libpython3.so"})
    assert run.returncode == 3, run.stdout + run.stderr
    lines = [line for line in run.stdout.splitlines() if line.startswith("LOG")]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"LOG {ERROR} logStatusError")
    assert "/nonexistent/libpython3.so" in lines[0] and "MBDFMU_PYTHON_LIBRARY" in lines[0]


def test_a_python_without_numpy_fails_instantiate_with_one_clear_line(c_host, unzipped, tmp_path):
    """Simulated: a folder first on MBDFMU_PYTHONPATH whose numpy cannot be imported."""
    (tmp_path / "numpy").mkdir()
    (tmp_path / "numpy" / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'numpy'\", name='numpy')\n")
    run = run_c_host(c_host, [unzipped], {"MBDFMU_PYTHONPATH": str(tmp_path)})
    assert run.returncode == 3, run.stdout + run.stderr
    lines = [line for line in run.stdout.splitlines() if line.startswith("LOG")]
    assert len(lines) == 1, lines
    assert "'numpy'" in lines[0] and "pip install numpy" in lines[0] and "MBDFMU_PYTHONPATH" in lines[0]


# ------------------------------------------------------------------ misuse (findings, section 1)

def refused_afterwards(h: Host) -> None:
    """After fmi2Error: values can still be read, stepping is refused, reset recovers."""
    assert h.get_real(VR["x"])[0] == OK
    assert h.step() == ERROR and "earlier call returned fmi2Error" in h.last()[2]
    assert h.status("fmi2Reset") == OK
    h.t = 0.0
    h.init()
    assert h.xs(3) == pytest.approx([closed_form(H * k)[0] for k in (1, 2, 3)], abs=1e-12)


@pytest.mark.parametrize("point, step, words", [
    (math.nan, H, "currentCommunicationPoint = nan"),
    (math.inf, H, "currentCommunicationPoint = inf"),
    (0.0, math.nan, "communicationStepSize = nan"),
    (0.0, math.inf, "communicationStepSize = inf"),
    (0.0, -1e-3, "communicationStepSize = -0.001"),
    (0.0, 0.0, "communicationStepSize = 0"),
    (0.5, H, "currentCommunicationPoint 0.5 is not the FMU's time 0.0"),
])
def test_invalid_communication_point_or_step_is_an_error(host, point, step, words):
    h = host().init()
    assert h.status("fmi2DoStep", point, step, 1) == ERROR
    assert h.last()[:2] == (ERROR, "logStatusError") and words in h.last()[2], h.last()
    refused_afterwards(h)


def test_a_huge_step_returns_the_exact_equilibrium(host):
    h = host().init()
    assert h.step(1e300) == OK
    assert h.get_real(VR["x"], VR["v"])[1] == pytest.approx([F / K, 0.0], abs=1e-15)
    frozen = host("b").init()         # the model skips its computation: only time moves
    assert frozen.status("fmi2SetBoolean", (ctypes.c_uint * 1)(VR["frozen"]), 1,
                         (ctypes.c_int * 1)(1)) == OK
    assert frozen.step(1e308) == OK
    h = frozen
    assert h.status("fmi2DoStep", 1e308, 1e308, 1) == ERROR
    assert "the time after the step, 1e+308 + 1e+308, is not finite" in h.last()[2]


def test_a_communication_point_within_the_relative_tolerance_is_accepted(host):
    h = host().init()
    h.xs(10)
    assert h.status("fmi2DoStep", h.t * (1 + 1e-12), H, 1) == OK


@pytest.mark.parametrize("stage", ["instantiated", "initialization mode"])
def test_step_before_initialization_is_an_error_naming_the_state(host, stage):
    h = host()
    h.fmu.setupExperiment(startTime=0.0)
    if stage == "initialization mode":
        h.fmu.enterInitializationMode()
    assert h.step() == ERROR
    assert f"fmi2DoStep is not allowed in state {stage.title()}" in h.last()[2], h.last()
    assert "allowed in: Step Complete" in h.last()[2]
    refused_afterwards(h)


def test_terminate_twice_and_step_after_terminate_are_errors(host):
    h = host().init()
    h.xs(2)
    assert h.status("fmi2Terminate") == OK
    assert h.step() == ERROR and "not allowed in state Terminated" in h.last()[2]
    h2 = host("b").init()
    assert h2.status("fmi2Terminate") == OK
    assert h2.status("fmi2Terminate") == ERROR
    assert "fmi2Terminate is not allowed in state Terminated" in h2.last()[2]
    assert h2.status("fmi2Reset") == OK


def test_unknown_value_reference_in_a_mixed_get_keeps_the_valid_value(host):
    h = host().init()
    h.xs(5)
    code, (x, missing) = h.get_real(VR["x"], 99999)
    assert code == ERROR and x == pytest.approx(closed_form(5 * H)[0], abs=1e-12)
    assert math.isnan(missing)
    assert "fmi2GetReal: unknown Real value reference 99999" in h.last()[2]
    refused_afterwards(h)


def test_unknown_value_reference_in_a_mixed_set_applies_the_valid_value(host):
    h = host().init()
    assert h.set_real([VR["F"], 99999], [2.0, 1.0]) == ERROR
    assert "fmi2SetReal: unknown Real value reference 99999" in h.last()[2]
    assert h.get_real(VR["F"]) == (OK, [2.0])


def test_unknown_string_reference_in_a_mixed_get_keeps_the_valid_string(host):
    h = host().init()
    values = (ctypes.c_char_p * 2)()
    code = h.status("fmi2GetString", (ctypes.c_uint * 2)(VR["label"], 777), 2, values)
    assert code == ERROR and values[0] == b"toy" and values[1] == b""
    assert "fmi2GetString: unknown String value reference 777" in h.last()[2]


def test_a_reference_of_another_type_is_an_error_naming_the_variable(host):
    h = host().init()
    code, values = h.get_real(VR["label"])
    assert code == ERROR and math.isnan(values[0])
    assert "value reference 100 is label, not a Real variable" in h.last()[2]


def test_setting_an_output_is_an_error(host):
    h = host().init()
    assert h.set_real([VR["x"]], [1.0]) == ERROR
    assert '"x" is an output and cannot be set' in h.last()[2]
    assert h.get_real(VR["x"]) == (OK, [X0])


def test_setting_a_fixed_parameter_after_initialization_is_an_error(host):
    h = host().init()
    assert h.set_real([VR["m"]], [100.0]) == ERROR
    assert 'parameter "m" is fixed' in h.last()[2]
    assert h.get_real(VR["m"]) == (OK, [M])


def test_tunable_string_parameter_can_be_set_after_initialization(host):
    h = host().init()
    new = (ctypes.c_char_p * 1)(b"renamed")
    assert h.status("fmi2SetString", (ctypes.c_uint * 1)(VR["label"]), 1, new) == OK
    values = (ctypes.c_char_p * 1)()
    assert h.status("fmi2GetString", (ctypes.c_uint * 1)(VR["label"]), 1, values) == OK
    assert values[0] == b"renamed"


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_input_is_discarded_and_a_finite_one_goes_on(host, value):
    h = host().init()
    assert h.set_real([VR["F"]], [value]) == DISCARD
    assert h.last()[:2] == (DISCARD, "logStatusDiscard") and '"F"' in h.last()[2]
    assert h.get_real(VR["F"]) == (OK, [F])
    assert h.xs(3) == pytest.approx([closed_form(H * k)[0] for k in (1, 2, 3)], abs=1e-12)


def set_integer(h, vr, value):
    return h.status("fmi2SetInteger", (ctypes.c_uint * 1)(vr), 1, (ctypes.c_int * 1)(value))


def test_a_discarded_step_stays_at_its_communication_point_and_can_be_retried(host):
    h = host().init()
    h.xs(3)
    assert set_integer(h, VR["fault"], 1) == OK
    assert h.step() == DISCARD and "fault input 1 asks to discard" in h.last()[2]
    time = ctypes.c_double()
    assert h.status("fmi2GetRealStatus", 2, ctypes.byref(time)) == OK   # fmi2LastSuccessfulTime
    assert time.value == pytest.approx(3 * H, abs=1e-15)
    assert set_integer(h, VR["fault"], 0) == OK
    assert h.xs(2) == pytest.approx([closed_form(H * k)[0] for k in (4, 5)], abs=1e-12)


def test_a_failing_step_is_an_error_with_the_exception_text(host):
    h = host().init()
    assert set_integer(h, VR["fault"], 2) == OK
    assert h.step() == ERROR
    assert "fmi2DoStep: RuntimeError: fault input 2 asks for an error" in h.last()[2]
    refused_afterwards(h)


def test_reset_then_rerun_is_bit_identical(host):
    h = host().init()
    first = h.xs(200)
    assert h.status("fmi2Reset") == OK
    h.t = 0.0
    assert h.init().xs(200) == first


def test_cancel_step_and_unsupported_status_kinds(host):
    h = host().init()
    value = ctypes.c_int()
    assert h.status("fmi2GetStatus", 0, ctypes.byref(value)) == DISCARD   # fmi2DoStepStatus
    terminated = ctypes.c_int(7)
    assert h.status("fmi2GetBooleanStatus", 3, ctypes.byref(terminated)) == OK
    assert terminated.value == 0
    assert h.status("fmi2CancelStep") == ERROR and "never returns fmi2Pending" in h.last()[2]


def test_derivatives_are_not_provided(host):
    h = host().init()
    out = (ctypes.c_double * 1)()
    code = h.status("fmi2GetDirectionalDerivative", (ctypes.c_uint * 1)(VR["x"]), 1,
                    (ctypes.c_uint * 1)(VR["F"]), 1, (ctypes.c_double * 1)(1.0), out)
    assert code == ERROR and "directional derivatives are not provided" in h.last()[2]


def test_null_arrays_and_unknown_log_categories_are_errors(host):
    h = host().init()
    assert h.status("fmi2GetReal", None, 1, None) == ERROR and "vr is NULL" in h.last()[2]
    h2 = host("b").init()
    names = (ctypes.c_char_p * 1)(b"logNoSuchThing")
    assert h2.status("fmi2SetDebugLogging", 1, 1, names) == ERROR
    assert "unknown log categories 'logNoSuchThing'" in h2.last()[2]


def test_debug_log_categories_filter_model_messages(host):
    h = host().init()
    h.xs(1)
    assert any(cat == "logModel" for _, cat, _ in h.messages)
    quiet = host("b", logging_on=False).init()
    quiet.xs(3)
    assert not any(cat == "logModel" for _, cat, _ in quiet.messages)
    assert quiet.set_real([VR["x"]], [0.0]) == ERROR        # reasons still reach the host
    assert quiet.last()[1] == "logStatusError"


# ------------------------------------------------------------------ FMU states

def get_state(h: Host):
    state = fmi2FMUstate()
    assert h.status("fmi2GetFMUstate", ctypes.byref(state)) == OK
    return state


def serialize(h: Host, state) -> bytes:
    size = ctypes.c_size_t()
    assert h.status("fmi2SerializedFMUstateSize", state, ctypes.byref(size)) == OK
    buffer = ctypes.create_string_buffer(size.value)
    assert h.status("fmi2SerializeFMUstate", state, buffer, size) == OK
    return buffer.raw


def deserialize(h: Host, blob: bytes) -> tuple[int, object]:
    state = fmi2FMUstate()
    data = ctypes.create_string_buffer(blob, max(len(blob), 1))
    return h.status("fmi2DeSerializeFMUstate", data, len(blob), ctypes.byref(state)), state


def test_state_into_the_same_and_another_instance_replays_bit_identical(host):
    a = host("a").init()
    a.xs(50)
    state = get_state(a)
    expected = a.xs(50)
    assert a.status("fmi2SetFMUstate", state) == OK
    a.t = 50 * H
    assert a.xs(50) == expected
    b = host("b").init()
    assert b.status("fmi2SetFMUstate", state) == OK
    b.t = 50 * H
    assert b.xs(50) == expected
    assert a.status("fmi2FreeFMUstate", ctypes.byref(state)) == OK and not state


def test_serialized_state_round_trips_bit_identical_into_a_third_instance(host):
    a = host("a").init()
    a.xs(50)
    state = get_state(a)
    blob = serialize(a, state)
    expected = a.xs(50)
    c = host("c")
    code, restored = deserialize(c, blob)
    assert code == OK
    assert serialize(c, restored) == blob
    assert c.status("fmi2SetFMUstate", restored) == OK
    c.t = 50 * H
    assert c.xs(50) == expected


def test_set_state_recovers_from_the_error_state(host):
    a = host("a").init()
    a.xs(5)
    state = get_state(a)
    expected = a.xs(5)
    assert a.set_real([VR["x"]], [1.0]) == ERROR
    assert a.status("fmi2SetFMUstate", state) == OK
    a.t = 5 * H
    assert a.xs(5) == expected


def mutations(blob: bytes, guid: str, marker: Path, count: int, seed: int = 20261127):
    """Byte strings that are not states of this FMU: each kind the reader must refuse."""
    rng = random.Random(seed)
    good = state_format.loads(blob, guid)

    class Touch:   # a pickle that would create `marker` when unpickled
        def __reduce__(self):
            return (open, (str(marker), "w"))
    pickled = pickle.dumps(Touch())
    fixed = [b"", pickled, pickle.dumps(good), blob[: len(blob) // 2], blob + b"\0",
             state_format.dumps(good, "{another-fmu}"),
             state_format.dumps({**good, "values": {**good["values"], "x": "text"}}, guid),
             state_format.dumps({**good, "model": {"state": [1.0, 2.0]}}, guid),
             state_format.dumps({**good, "time": math.nan}, guid),
             state_format.dumps({**good, "state": "Error"}, guid)]
    deep = []
    for _ in range(state_format.MAX_DEPTH + 3):
        deep = [deep]
    fixed.append(_raw_state(deep, guid))
    yield from fixed
    for i in range(count - len(fixed)):
        kind = i % 4
        if kind == 0:      # random bytes of random length
            yield bytes(rng.randrange(256) for _ in range(rng.randrange(0, 300)))
        elif kind == 1:    # one byte flipped
            data = bytearray(blob)
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            yield bytes(data)
        elif kind == 2:    # truncated
            yield blob[: rng.randrange(len(blob))]
        else:              # random header with a payload length claiming up to 2^64 - 1
            yield state_format.HEADER.pack(state_format.MAGIC, 1, 0, rng.getrandbits(64),
                                           state_format.fmu_digest(guid)) + bytes(40)


def _raw_state(tree, guid: str) -> bytes:
    """A well-formed blob (valid checksum) around a tree nested deeper than the limit."""
    def encode(node):
        return b"l" + len(node).to_bytes(4, "little") + b"".join(encode(n) for n in node)
    import hashlib
    payload = encode(tree)
    head = state_format.HEADER.pack(state_format.MAGIC, 1, 0, len(payload),
                                    state_format.fmu_digest(guid))
    return head + payload + hashlib.sha256(head + payload).digest()


def test_deserialize_refuses_1000_corrupt_or_foreign_blobs_and_executes_nothing(host, tmp_path):
    h = host().init()
    h.xs(3)
    blob = serialize(h, get_state(h))
    guid = h.fmu.guid
    marker = tmp_path / "pwned"
    seen = 0
    for data in mutations(blob, guid, marker, count=1000):
        code, _ = deserialize(h, data)
        assert code == ERROR, data[:80]
        assert h.last()[:2] == (ERROR, "logStatusError")
        assert "fmi2DeSerializeFMUstate: refused:" in h.last()[2], h.last()
        seen += 1
    assert seen == 1000 and not marker.exists()
    assert h.status("fmi2Reset") == OK                # the host and the instance survive
    h.t = 0.0
    assert h.init().xs(2) == pytest.approx([closed_form(H)[0], closed_form(2 * H)[0]], abs=1e-12)


# ------------------------------------------------------------------ build

def test_no_compiler_fails_the_build_with_one_line(monkeypatch, tmp_path, workdir):
    from fmu_build.native import CompileError, compile_wrapper
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(CompileError) as info:
        compile_wrapper(tmp_path)
    message = str(info.value)
    assert "\n" not in message and "no C compiler found" in message and "apt-get install gcc" in message


def test_the_wrapper_is_compiled_once_per_source_and_compiler(workdir):
    from fmu_build.native import compile_wrapper
    first = compile_wrapper(workdir / "cache")
    stamp = first.stat().st_mtime_ns
    assert compile_wrapper(workdir / "cache") == first and first.stat().st_mtime_ns == stamp


def test_same_inputs_give_the_same_fmu_bytes(workdir, toy):
    again = build_toy(workdir / "again.fmu", cache_dir=workdir / "cache")
    assert again.read_bytes() == toy.read_bytes()


# ------------------------------------------------------------------ Ecos (pip install ecospy; apt-get install libtbb12)

def test_ecos_command_line_host_runs_the_fmu_from_a_clean_environment(toy, tmp_path):
    """Ecos' C++ command line has no Python inside; its CSV has 6 decimals."""
    ecospy = pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    import subprocess
    shipped = Path(ecospy.__file__).parent / "binaries" / "ecos"
    ecos = tmp_path / "ecos"
    shutil.copy(shipped, ecos)
    ecos.chmod(0o755)
    run = subprocess.run([str(ecos), "simulate", "--path", str(toy), "--stopTime", "1",
                          "--stepSize", repr(H)], capture_output=True, text=True, timeout=120,
                         cwd=tmp_path, env=hosts.clean_env(tmp_path))
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    rows = (tmp_path / f"{IDENTIFIER}.csv").read_text().splitlines()
    header = [name.strip() for name in rows[0].split(",")]
    columns = list(zip(*(map(str.strip, row.split(",")) for row in rows[1:])))
    times = [float(t) for t in columns[header.index("time")]]
    xs = [float(x) for x in columns[header.index("instance::x[REAL]")]]
    assert len(times) >= 100
    for t, x in zip(times, xs):
        assert abs(x - closed_form(t)[0]) <= 5e-7, (t, x)


def test_ecospy_runs_the_fmu_like_the_closed_form(toy):
    pytest.importorskip("ecospy", reason="pip install ecospy (and apt-get install libtbb12)")
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure
    structure = EcosSimulationStructure()
    structure.add_model("toy", str(toy))
    simulation = EcosSimulation(structure=structure, step_size=H)
    simulation.init()
    simulation.step(100)
    t, x = simulation.get_time(), simulation.get_real("toy::x")
    simulation.terminate()
    simulation.free()
    assert t == pytest.approx(1.0, abs=1e-12) and abs(x - closed_form(t)[0]) <= 1e-9
