"""The toy FMU of the native-wrapper tests: its variable table, build and closed form."""

from __future__ import annotations

import ast
import math
from pathlib import Path

from mbdfmu.fmu_build.model_description import DefaultExperiment
from mbdfmu.fmu_build.package import write_fmu
from mbdfmu.fmu_build.runtime.variables import Variable

SOURCE = Path(__file__).with_name("mass_spring.py")
IDENTIFIER = "MassSpring"
# Parameters of the closed form (SI): mass, stiffness, damping, initial state, force.
M, K, C, X0, V0, F = 2.0, 50.0, 1.0, 0.1, 0.0, 0.5
# Value references (per FMI type), named for the tests.
VR = {"m": 0, "k": 1, "c": 2, "x0": 3, "v0": 4, "F": 5, "x": 6, "v": 7,
      "fault": 50, "frozen": 60, "label": 100}



def transition_source() -> str:
    """The text of mass_spring.transition, the toy's exact step (for FMUs built from
    other runtimes in the benchmarks, which must step the same model)."""
    text = SOURCE.read_text()
    node = next(n for n in ast.parse(text).body
                if isinstance(n, ast.FunctionDef) and n.name == "transition")
    return ast.get_source_segment(text, node)


VARIABLES = (
    Variable("m", VR["m"], causality="parameter", start=M, unit="kg", description="mass"),
    Variable("k", VR["k"], causality="parameter", start=K, unit="N/m", description="stiffness"),
    Variable("c", VR["c"], causality="parameter", start=C, unit="N.s/m", description="damping"),
    Variable("x0", VR["x0"], causality="parameter", start=X0, unit="m", description="x at t = 0"),
    Variable("v0", VR["v0"], causality="parameter", start=V0, unit="m/s", description="v at t = 0"),
    Variable("F", VR["F"], causality="input", start=F, unit="N", description="applied force"),
    Variable("x", VR["x"], causality="output", unit="m", description="position",
             dependencies=(), initial_dependencies=("x0",)),
    Variable("v", VR["v"], causality="output", unit="m/s", description="velocity",
             dependencies=(), initial_dependencies=("v0",)),
    Variable("fault", VR["fault"], type="Integer", causality="input", start=0,
             description="1: discard the next step, 2: fail it with an error"),
    Variable("frozen", VR["frozen"], type="Boolean", causality="input", start=False,
             description="hold the state still"),
    Variable("label", VR["label"], type="String", causality="parameter", variability="tunable",
             start="toy", description="free text"),
)


def build_toy(output: Path, cache_dir: Path | None = None, source: str | None = None,
              stop_time: float = 1.0, step_size: float = 0.01) -> Path:
    """Write the toy FMU (``source`` replaces the model module, for variants)."""
    return write_fmu(output, IDENTIFIER, VARIABLES, source or SOURCE.read_text(),
                     description="Damped mass-spring driven by a force (test model)",
                     log_categories={"logModel": "The initial state"},
                     default_experiment=DefaultExperiment(0.0, stop_time, step_size),
                     cache_dir=cache_dir)


def closed_form(t, m=M, k=K, c=C, x0=X0, v0=V0, force=F):
    """x(t), v(t) of m x'' + c x' + k x = force (constant), underdamped, from t = 0."""
    w0 = math.sqrt(k / m)
    zeta = c / (2 * math.sqrt(k * m))
    wd = w0 * math.sqrt(1 - zeta ** 2)
    y0 = x0 - force / k
    a, b = y0, (v0 + zeta * w0 * y0) / wd
    e, cs, sn = math.exp(-zeta * w0 * t), math.cos(wd * t), math.sin(wd * t)
    x = force / k + e * (a * cs + b * sn)
    v = e * ((-zeta * w0 * a + wd * b) * cs + (-zeta * w0 * b - wd * a) * sn)
    return x, v
