"""Directional derivatives (fmi2GetDirectionalDerivative, fmi3GetDirectionalDerivative)
against central finite differences of the FMU itself at the same communication point:
every output and state derivative with respect to every input (set the input, read the
values back) and every continuous state (the FMU's serialized state with that state
moved, deserialized into the FMU, the values read back); to 1e-6 of each column's size.

The FMU's values at a moved state are what the FMU itself computes there (it recomputes
its outputs when a state is restored); the directional derivatives come from the
equations at the communication point (docs/fmu.md, "Directional derivatives")."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "tests") not in sys.path:
    sys.path.insert(0, str(ROOT / "tests"))

fmpy = pytest.importorskip("fmpy")
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from fmu_models.fmi3_host import Host3  # noqa: E402
from mbdfmu.fmu_build import build  # noqa: E402
from mbdfmu.fmu_build.runtime import state_format  # noqa: E402

# (FMU source, start values, inputs set and the steps taken before the check)
CASES = {
    "crane": (ROOT / "scenarios" / "hydraulic_crane" / "crane.toml", {},
              {"cylinder.actuator": 9000.0}, [0.05, 0.05]),
    "slider_force": (ROOT / "scenes" / "slider_force.toml", {},
                     {"push.fx": 3.0, "push.fy": -1.0}, [0.05]),
    "pendulum_torque": (ROOT / "scenes" / "pendulum_torque.toml", {},
                        {"drive.torque": 2.0}, [0.1, 0.1]),
    "hydraulics": (ROOT / "scenarios" / "hydraulic_crane" / "hydraulic_cylinder.py",
                   {"force0": 8422.757016042891, "valve": 0.4},
                   {"rate": 0.05, "length": 0.86}, [0.01, 0.01]),
    "oscillator": (ROOT / "scenarios" / "two_mass_oscillator" / "oscillator.py",
                   {"cc": 1000.0, "dc": 2.0, "x0": 0.01},
                   {"x_other": 0.003, "v_other": -0.2, "force": 1.0}, [0.01]),
}
RELATIVE = 1e-6


class Fmu:
    """One FMI 2.0 instance of a case, stepped to its check point."""

    def __init__(self, path: Path, start: dict, inputs: dict, steps: list[float]):
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName="dd")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(start)
        self.fmu.exitInitializationMode()
        t = 0.0
        for h in steps:
            self.set(inputs)
            self.fmu.doStep(t, h)
            t += h
        self.set({k: v * 1.1 for k, v in inputs.items()})   # inputs set since the step
        self.states = [v.derivative.name for v in self.md.modelVariables
                       if v.derivative is not None]
        self.unknowns = [v.name for v in self.md.modelVariables
                         if v.causality == "output" or v.name.startswith("der(")
                         or (v.derivative is not None and v.causality == "local")]
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]

    def set(self, values: dict) -> None:
        if values:
            self.fmu.setReal([self.vr[n] for n in values], list(map(float, values.values())))

    def get(self) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vr[n] for n in self.unknowns]))

    def directional(self, known: str) -> np.ndarray:
        return np.array(self.fmu.getDirectionalDerivative([self.vr[n] for n in self.unknowns],
                                                          [self.vr[known]], [1.0]))

    def input_difference(self, name: str, delta: float) -> np.ndarray:
        value = self.fmu.getReal([self.vr[name]])[0]
        columns = []
        for sign in (1, -1):
            self.set({name: value + sign * delta})
            columns.append(self.get())
        self.set({name: value})
        return (columns[0] - columns[1]) / (2 * delta)

    def state_difference(self, name: str, delta: float) -> np.ndarray:
        """Central difference through the serialized state with ``name`` moved."""
        saved = self.fmu.getFMUstate()
        tree = state_format.loads(bytes(self.fmu.serializeFMUstate(saved)), self.md.guid)
        columns = []
        for sign in (1, -1):
            moved = _move(tree, name, sign * delta, self)
            blob = state_format.dumps(moved, self.md.guid)
            self.fmu.setFMUstate(self.fmu.deSerializeFMUstate(blob))
            columns.append(self.get())
        self.fmu.setFMUstate(saved)
        self.fmu.freeFMUstate(saved)
        return (columns[0] - columns[1]) / (2 * delta)


def _move(tree: dict, name: str, delta: float, fmu: Fmu) -> dict:
    """A copy of an FMU state tree with the continuous state ``name`` moved by ``delta``."""
    import copy
    tree = copy.deepcopy(tree)
    model = tree["model"]
    if "sim" in model:                       # a scene: q and q' of the integrator
        body, coordinate = name.rsplit(".", 1)
        bodies = [b for b in dict.fromkeys(s.rsplit(".", 1)[0] for s in fmu.states)]
        k = ("x", "y", "phi", "vx", "vy", "omega").index(coordinate)
        key, index = ("q" if k < 3 else "qd"), 3 * bodies.index(body) + k % 3
        model["sim"]["integrator"][key][index] += delta
    else:                                    # a companion: its state table
        model["state"][name] += delta
    return tree


def _check(fmu: Fmu, columns: dict[str, np.ndarray], name: str, fd: np.ndarray,
           delta: float) -> float:
    """The largest difference of the column from the central difference, relative to the
    column's size; differences below the central difference's own round-off (a few ulps of
    the row's value, at least 1, divided by the step: a derivative that is zero, such as a
    constrained acceleration, differences to about 1e-9) count as none."""
    dd = columns[name]
    scale = max(float(np.max(np.abs(fd))), 1e-300)
    noise = 8 * np.finfo(float).eps * np.maximum(1.0, np.abs(fmu.get())) / delta  # per row
    return float(np.max(np.maximum(np.abs(dd - fd) - noise, 0.0))) / scale


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    root, built = tmp_path_factory.mktemp("dd"), {}

    def get(case: str, version: int = 2):
        if (case, version) not in built:
            source = CASES[case][0]
            built[case, version] = build(source, root / f"{case}{version}.fmu",
                                         fmi_version=version)
        return built[case, version]
    return get


@pytest.mark.parametrize("case", list(CASES))
def test_directional_derivatives_equal_central_differences_of_the_fmu(case, fmus):
    _, start, inputs, steps = CASES[case]
    fmu = Fmu(fmus(case), start, inputs, steps)
    assert fmu.md.coSimulation.providesDirectionalDerivative
    assert fmu.states and fmu.inputs
    knowns = fmu.inputs + fmu.states
    columns = {k: fmu.directional(k) for k in knowns}
    worst = {}
    for name in fmu.inputs:
        delta = 1e-6 * max(1.0, abs(fmu.fmu.getReal([fmu.vr[name]])[0]))
        worst[name] = _check(fmu, columns, name, fmu.input_difference(name, delta), delta)
    for name in fmu.states:
        delta = 1e-6 * max(1.0, abs(fmu.fmu.getReal([fmu.vr[name]])[0]))
        worst[name] = _check(fmu, columns, name, fmu.state_difference(name, delta), delta)
    print(case, f"largest relative difference {max(worst.values()):.1e}")
    assert max(worst.values()) < RELATIVE, {k: f"{v:.1e}" for k, v in worst.items()}
    # outputs do not follow inputs set since the step (no direct feedthrough)...
    outputs = [i for i, n in enumerate(fmu.unknowns)
               if fmu.md.modelVariables[[v.name for v in fmu.md.modelVariables].index(n)]
               .causality == "output"]
    feedthrough = {d.name for u in fmu.md.outputs for d in u.dependencies} & set(fmu.inputs)
    if not feedthrough:
        assert all(np.all(columns[n][outputs] == 0) for n in fmu.inputs)
    # ...and a linear combination of seeds is the same combination of columns
    seeds = np.linspace(0.5, 1.5, len(knowns))
    combined = np.array(fmu.fmu.getDirectionalDerivative(
        [fmu.vr[n] for n in fmu.unknowns], [fmu.vr[k] for k in knowns], list(seeds)))
    expected = sum(s * columns[k] for s, k in zip(seeds, knowns))
    assert np.allclose(combined, expected, rtol=1e-6, atol=1e-9 * np.max(np.abs(expected)))


def test_fmi3_directional_derivatives_equal_fmi2(fmus):
    _, start, inputs, steps = CASES["crane"]
    fmu2 = Fmu(fmus("crane"), start, inputs, steps)
    host = Host3(fmus("crane", 3))
    host.init()
    for k, h in enumerate(steps):
        host.set(**inputs)
        assert host.step(h)[0] == 0
    host.set(**{k: v * 1.1 for k, v in inputs.items()})
    unknowns = [host.vr[n] for n in fmu2.unknowns]
    for known in ("cylinder.actuator", "boom.phi", "load.omega"):
        got = host.fmu.getDirectionalDerivative(unknowns, [host.vr[known]], [1.0])
        assert list(got) == list(fmu2.directional(known)), known


def test_directional_derivatives_refuse_what_is_not_a_known_or_an_unknown(fmus):
    _, start, inputs, steps = CASES["pendulum_torque"]
    fmu = Fmu(fmus("pendulum_torque"), start, inputs, steps)
    out = fmu.vr[fmu.unknowns[0]]
    for unknowns, knowns in (([out], [fmu.vr["rod.mass"]]), ([fmu.vr["drive.torque"]],
                                                             [fmu.vr["drive.torque"]])):
        with pytest.raises(FMICallException):
            fmu.fmu.getDirectionalDerivative(unknowns, knowns, [1.0])
