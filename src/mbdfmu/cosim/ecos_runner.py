"""A scenario in Ecos (a C++ co-simulation engine) through its Python API, ecospy.

Ecos loads the scenario's SSP file (``ssp_runner.export_ssp``: the same file fmpy's SSP
runner and libcosim read), applies its start values with ``init(parameter_set=...)`` (Ecos
applies only the SSD parameter sets of the name it is given, across all components: every
component's set is named ``ssp_runner.PARAMETER_SET``) and steps with its fixed-step
algorithm, which is Jacobi: every instance steps from t to t + h on the inputs of time t.
At initialization it passes outputs to inputs, so connected inputs start at the upstream
outputs of t = 0, as the fmpy master's ``start="exchange"`` and libcosim.

Ecos passes outputs to inputs right after each step, before anything can read them, so
an output with direct feedthrough (the controller's force, the cylinder's force) read from
Ecos already reflects the inputs of the new time, where the other masters record the
value they passed on. For a recorded output that feeds a connection, this runner
therefore reads the connected input: the value the exchange passed on, as the others
record it (the mechanism's states agree with the other masters either way).

The FMUs run in-process (ecospy's library loads them): mbdfmu FMUs use this Python.
Requires ``pip install ecospy`` and Debian's ``libtbb12``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..result import Result
from .scenario import Scenario
from .settings import CosimError, fixed_steps
from .ssp_runner import PARAMETER_SET, export_ssp
from .threads import one_core


def _ecospy():
    try:
        from ecospy.EcosSimulation import EcosSimulation
    except (ImportError, OSError) as exc:  # OSError: its library lacks libtbb.so.12
        raise CosimError(f"Ecos is not available ({exc}): pip install ecospy, and "
                         "apt-get install libtbb12") from None
    return EcosSimulation


def _identifiers(scenario: Scenario, names: list[str]) -> list[str]:
    """Ecos' identifier to read for each recorded name (a connected output: its input)."""
    passed = {}
    for c in scenario.connections:
        passed.setdefault(c.source, c.target)
    return [passed.get(name, name) for name in names]


def _read(simulation, names: list[str]) -> list[float]:
    row = []
    for name in names:
        inst, var = name.split(".", 1)
        try:
            row.append(simulation.get_real(f"{inst}::{var}"))
        except Exception as exc:  # noqa: BLE001 - ecospy raises plain exceptions
            raise CosimError(f'Ecos cannot read "{name}": {exc}') from None
    return row


def _run(EcosSimulation, path: Path, h: float, n: int, identifiers) -> list[list[float]]:
    """Load the SSP file in Ecos, initialize with the start values, take n steps of h; the
    rows of ``identifiers`` at t = 0, h, ..., n h."""
    try:
        simulation = EcosSimulation(ssp_path=str(path), step_size=h)
    except Exception as exc:  # noqa: BLE001
        raise CosimError(f"Ecos cannot load {path}: {exc}") from None
    try:
        if simulation.init(parameter_set=PARAMETER_SET) is False:
            raise CosimError(f"Ecos could not initialize {path}")
        rows = [_read(simulation, identifiers)]
        for k in range(1, n + 1):
            simulation.step(1)
            if abs(simulation.get_time() - k * h) > 1e-9 * max(1.0, k * h):
                raise CosimError("Ecos stopped stepping (an FMU refused a step)", t=(k - 1) * h)
            rows.append(_read(simulation, identifiers))
        simulation.terminate()
    finally:
        simulation.free()
    return rows


def run_ecos(scenario: Scenario, fmus: dict[str, Path], ssp_path: str | Path,
             step: float | None = None, t_end: float | None = None,
             record: list[str] | None = None, algorithm: str | None = None) -> Result:
    """Export the scenario to ``ssp_path``, load it in Ecos and run it (Jacobi); every
    recorded variable at every communication point, t = 0 included."""
    from fmpy import read_model_description

    EcosSimulation = _ecospy()
    h, t_end, n = fixed_steps(scenario, step, t_end, algorithm, "Ecos' fixed-step algorithm")
    names = list(record if record is not None else scenario.recorded())
    path = export_ssp(scenario, fmus, ssp_path, h, t_end, names)
    with one_core():        # Ecos' TBB threads on this core (threads.py)
        rows = _run(EcosSimulation, path, h, n, _identifiers(scenario, names))
    units = {}
    for inst in scenario.instances:
        md = read_model_description(str(fmus[inst.name]))
        units.update({f"{inst.name}.{v.name}": v.unit or "" for v in md.modelVariables})
    return Result(time=np.arange(n + 1) * h, names=names, values=np.array(rows, dtype=float),
                  units={nm: units.get(nm, "") for nm in names}, method="Ecos jacobi (SSP)",
                  stats={"steps": int(n)})
