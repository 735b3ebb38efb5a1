"""ECCO in OSP libcosim: energy-conservation-based co-simulation (Sadjina and Pedersen,
"Energy conservation and coupling error reduction in non-iterative co-simulations", and
Sadjina et al., "Energy conservation and power bonds in co-simulations").

The FMUs declare their power ports (an effort and the flow it acts on: a force and the
velocity, a torque and the angular velocity; ``fmu_build/osp.py``); the bond is the pair
of ports the scenario connects crosswise, and ``ecco_config.py`` writes libcosim's
``OspSystemStructure.xml`` with the ECCO algorithm for it, which libcosim loads
(``CosimExecution.from_osp_config_file``). A scenario's ``[power_bonds]``, if given, must
name the same bond. libcosim's ECCO algorithm measures the energy that the coupling
creates or destroys at that bond over each macro step (the residual of the power each
side sees) and controls the communication step with a PI controller to keep it within its
tolerances; the connections stay Jacobi with zero-order hold.

``energy_residual(times, values, bonds)`` integrates the bond's power balance from recorded
samples (the trapezoidal rule on each side's power): the interface energy residual, zero
for an exact coupling.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..result import Result
from .ecco_config import FILE_NAME, check_scenario_table, find_bond, write_structure
from .libcosim_runner import NS, _ns
from .scenario import Scenario, check_variables
from .settings import CosimError
from .threads import one_core

# ECCO's tolerances on the bond's energy residual (J), its step limits (relative to the
# initial step h) and the bounds of one step change (the PI controller's gain).
ECCO_RTOL = 1e-4
ECCO_ATOL = 1e-4
MIN_STEP_FACTOR, MAX_STEP_FACTOR = 0.01, 10.0
MIN_CHANGE, MAX_CHANGE = 0.2, 1.5
SAFETY, P_GAIN, I_GAIN = 0.8, 0.2, 0.15       # libcosim's defaults
RESIDUAL = "interface.energy_residual"


def bond_variables(bonds: dict) -> list[str]:
    """The four recorded variables of the power bond: each side's effort and flow."""
    return [f"{inst}.{name}" for inst, pair in bonds.items() for name in pair]


def energy_residual(times, values: dict, bonds: dict) -> np.ndarray:
    """Cumulative interface energy residual (J) at each time: the energy one side's output
    effort delivers against the flow it receives, minus what the other side receives,
    trapezoidal rule on the sampled powers. ``bonds``: instance -> (its input, its output),
    the effort-taking side first."""
    (a, (ea, fa)), (b, (eb, fb)) = bonds.items()
    # a's effort input comes from b's effort output: b delivers y_e(b) u_f(b), a receives
    # u_e(a) y_f(a)
    sent = np.asarray(values[f"{b}.{fb}"]) * np.asarray(values[f"{b}.{eb}"])
    received = np.asarray(values[f"{a}.{ea}"]) * np.asarray(values[f"{a}.{fa}"])
    power = sent - received
    t = np.asarray(times, dtype=float)
    out = np.zeros_like(t)
    out[1:] = np.cumsum(np.diff(t) * (power[1:] + power[:-1]) / 2)
    return out


def _load(structure: Path):
    """libcosim's execution of the OspSystemStructure.xml at ``structure``."""
    from libcosimpy.CosimExecution import CosimExecution, get_last_error_message
    try:
        return CosimExecution.from_osp_config_file(str(structure))
    except AssertionError:
        raise CosimError(f"libcosim cannot load {structure}: {get_last_error_message()}") from None


def _simulate(execution, index, vr, names, t_end, capacity):
    """Run to ``t_end`` recording ``names`` at every macro step: (times, {name: values})."""
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import get_last_error_message
    from libcosimpy.CosimObserver import CosimObserver

    series = CosimObserver.create_time_series(buffer_size=min(capacity, 2_000_000))
    execution.add_observer(series)
    for name in names:
        inst, var = name.split(".", 1)
        series.start_time_series(index[inst], value_reference=vr[inst][var],
                                 variable_type=CosimVariableType.REAL)
    if not execution.simulate_until(target_time=_ns(t_end, "t_end")):
        raise CosimError(f"libcosim (ECCO) stopped at t = "
                         f"{execution.status().current_time / NS:g} s: {get_last_error_message()}")
    columns, times = {}, None
    for name in names:
        inst, var = name.split(".", 1)
        t, _, values = series.time_series_real_samples(index[inst], vr[inst][var], from_step=0,
                                                       sample_count=capacity)
        times = np.asarray(t, dtype=np.int64) * (1.0 / NS)
        columns[name] = np.asarray(values, dtype=float)
    n = min(len(c) for c in columns.values())
    return times[:n], {k: v[:n] for k, v in columns.items()}


def run_ecco(scenario: Scenario, fmus, step: float | None = None, t_end: float | None = None,
             record: list[str] | None = None, rtol: float | None = None,
             atol: float | None = None, structure: Path | None = None,
             start_step: float | None = None) -> Result:
    """Run the scenario with libcosim's ECCO algorithm (step bounds from ``step``) from the
    ``OspSystemStructure.xml`` written for the FMUs' power bond (at ``structure``, by
    default beside the first FMU); every recorded variable and the bond's variables at
    every macro step, and the interface energy residual. ``start_step`` (default
    ``step``): libcosim's controller takes its first two steps at it, whatever the
    tolerance, and then changes each step by a factor from ``MIN_CHANGE`` to ``MAX_CHANGE``."""
    from fmpy import read_model_description
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    h = float(step or scenario.step)
    t_end = float(t_end or scenario.t_end)
    _ns(h, "the step")
    descriptions = {i.name: read_model_description(str(fmus[i.name])) for i in scenario.instances}
    check_variables(scenario, descriptions)
    bond = find_bond(scenario, fmus)
    check_scenario_table(scenario, bond)
    bonds = bond.as_table()
    vr = {inst: {v.name: v.valueReference for v in md.modelVariables}
          for inst, md in descriptions.items()}
    unit = {inst: {v.name: v.unit or "" for v in md.modelVariables}
            for inst, md in descriptions.items()}
    types = {f"{inst}.{v.name}": v.type for inst, md in descriptions.items()
             for v in md.modelVariables}
    first = float(start_step or h)
    _ns(first, "the start step")
    params = {"SafetyFactor": SAFETY, "StepSize": first,
              "MinimumStepSize": min(MIN_STEP_FACTOR * h, first),
              "MaximumStepSize": MAX_STEP_FACTOR * h, "MinimumChangeRate": MIN_CHANGE,
              "MaximumChangeRate": MAX_CHANGE, "ProportionalGain": P_GAIN,
              "IntegralGain": I_GAIN, "RelativeTolerance": rtol or ECCO_RTOL,
              "AbsoluteTolerance": atol or ECCO_ATOL}
    structure = Path(structure or Path(next(iter(fmus.values()))).parent / FILE_NAME)
    write_structure(scenario, fmus, bond, structure, step=h, params=params, types=types)
    log_output_level(CosimLogLevel.WARNING)
    names = list(dict.fromkeys(list(record if record is not None else scenario.recorded())
                               + bond_variables(bonds)))
    with one_core():        # as run_libcosim: libcosim's worker threads on this core
        execution = _load(structure)
        index = {i.name: execution.slave_index_from_instance_name(i.name)
                 for i in scenario.instances}
        times, columns = _simulate(execution, index, vr, names, t_end,
                                   int(10 * t_end / params["MinimumStepSize"]) + 16)
        del execution
    columns[RESIDUAL] = energy_residual(times, columns, bonds)
    n = len(times)
    out_names = names + [RESIDUAL]
    units = {nm: unit[nm.split(".", 1)[0]].get(nm.split(".", 1)[1], "") for nm in names}
    units[RESIDUAL] = "J"
    return Result(time=times, names=out_names,
                  values=np.column_stack([columns[k] for k in out_names]), units=units,
                  method="libcosim ecco", stats={"steps": int(n - 1),
                                                 "mean_step": float(times[-1] / max(n - 1, 1))})
