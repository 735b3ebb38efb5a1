"""Every misuse of the FMI API from the reliability findings (section 1), replayed on the
native runtime's toy FMU through fmpy's low-level FMU2Slave: the status, the logged
reason, and what still works afterwards; FMU states, serialization and a fuzz test of
fmi2DeSerializeFMUstate.
"""

from __future__ import annotations

import ctypes
import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:       # this checkout's fmu_build, not an installed copy
    sys.path.insert(0, str(ROOT))

pytest.importorskip("fmpy")
from fmu_models.harness import (DISCARD, ERROR, H, OK, deserialize, get_state,  # noqa: E402,F401
                                host, mutations, refused_afterwards, serialize, set_integer,
                                toy, unzipped, workdir)
from fmu_models.toy import F, K, M, VR, X0, closed_form  # noqa: E402


# ------------------------------------------------------------------ misuse (findings, section 1)

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


def test_unknown_string_reference_in_a_mixed_set_applies_the_valid_string(host):
    h = host().init()
    new = (ctypes.c_char_p * 2)(b"renamed", b"lost")
    assert h.status("fmi2SetString", (ctypes.c_uint * 2)(VR["label"], 777), 2, new) == ERROR
    assert "fmi2SetString: unknown String value reference 777" in h.last()[2]
    values = (ctypes.c_char_p * 1)()
    assert h.status("fmi2GetString", (ctypes.c_uint * 1)(VR["label"]), 1, values) == OK
    assert values[0] == b"renamed"


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
