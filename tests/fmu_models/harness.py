"""Test harness of the native-wrapper tests: the toy FMU's fixtures, one instance driven
through fmpy's low-level FMU2Slave with every log message kept, FMU-state helpers, and
byte strings that are not states of the FMU (for the deserialization fuzz test)."""

from __future__ import annotations

import ctypes
import hashlib
import math
import pickle
import random
from pathlib import Path

import fmpy
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2FMUstate)

from mbdfmu.fmu_build.runtime import state_format
from fmu_models.toy import F, IDENTIFIER, VR, build_toy, closed_form

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
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=directory, instanceName=name,
                             modelIdentifier=md.coSimulation.modelIdentifier)
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


def refused_afterwards(h: Host) -> None:
    """After fmi2Error: values can still be read, stepping is refused, reset recovers."""
    assert h.get_real(VR["x"])[0] == OK
    assert h.step() == ERROR and "earlier call returned fmi2Error" in h.last()[2]
    assert h.status("fmi2Reset") == OK
    h.t = 0.0
    h.init()
    assert h.xs(3) == pytest.approx([closed_form(H * k)[0] for k in (1, 2, 3)], abs=1e-12)


def set_integer(h, vr, value):
    return h.status("fmi2SetInteger", (ctypes.c_uint * 1)(vr), 1, (ctypes.c_int * 1)(value))


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
    payload = encode(tree)
    head = state_format.HEADER.pack(state_format.MAGIC, 1, 0, len(payload),
                                    state_format.fmu_digest(guid))
    return head + payload + hashlib.sha256(head + payload).digest()
