"""ECCO in OSP libcosim: energy-conservation-based co-simulation (Sadjina and Pedersen,
"Energy conservation and coupling error reduction in non-iterative co-simulations", and
Sadjina et al., "Energy conservation and power bonds in co-simulations").

A scenario's ``[power_bonds]`` names, for two instances, the effort input and the flow
output of each side (a force and the velocity it acts on, a torque and its angular
velocity). libcosim's ECCO algorithm measures the energy that the coupling creates or
destroys at that bond over each macro step (the residual of the power each side sees) and
controls the communication step with a PI controller to keep it within its tolerances;
the connections stay Jacobi with zero-order hold. Built through libcosimpy's API
(``CosimAlgorithm.create_ecco_algorithm``, ``add_power_bond``), from the same description
as the fixed-step runs.

libcosim's step control (libcosimpy 0.0.6) reads the bond from the first outgoing
connection of its first two slaves, whatever ``add_power_bond`` declared: the runner
therefore adds the two bonded instances first, and their bond connections (the flow to
the effort's side, then the effort back) before the others.

``energy_residual(result, scenario)`` integrates the bond's power balance from recorded
samples (the trapezoidal rule on each side's power): the interface energy residual, zero
for an exact coupling.
"""

from __future__ import annotations

import numpy as np

from ..result import Result
from .libcosim_runner import NS, _build_from_description, _ns
from .scenario import Scenario, check_variables
from .settings import CosimError

# ECCO's tolerances on the bond's energy residual (J), its step limits (relative to the
# initial step h) and the bounds of one step change (the PI controller's gain).
ECCO_RTOL = 1e-4
ECCO_ATOL = 1e-4
MIN_STEP_FACTOR, MAX_STEP_FACTOR = 0.01, 10.0
MIN_CHANGE, MAX_CHANGE = 0.2, 1.5
RESIDUAL = "interface.energy_residual"


def bond_variables(scenario: Scenario) -> list[str]:
    """The four recorded variables of the power bond: each side's effort and flow."""
    return [f"{inst}.{name}" for inst, pair in scenario.power_bonds.items() for name in pair]


def bond_first(scenario: Scenario) -> Scenario:
    """The scenario with the bonded instances first and the bond's two connections (a's
    flow to b, b's effort to a) ahead of the others (see the module docstring)."""
    from dataclasses import replace

    (a, (ea, fa)), (b, (eb, fb)) = scenario.power_bonds.items()
    first = [c for c in scenario.connections if c.source == f"{a}.{fa}"] + \
        [c for c in scenario.connections if c.source == f"{b}.{fb}" and c.target == f"{a}.{ea}"]
    rest = [c for c in scenario.connections if c not in first]
    instances = sorted(scenario.instances, key=lambda i: (i.name != a, i.name != b))
    return replace(scenario, instances=tuple(instances), connections=tuple(first + rest))


def energy_residual(times, values: dict, scenario: Scenario) -> np.ndarray:
    """Cumulative interface energy residual (J) at each time: the energy one side's output
    effort delivers against the flow it receives, minus what the other side receives,
    trapezoidal rule on the sampled powers."""
    (a, (ea, fa)), (b, (eb, fb)) = scenario.power_bonds.items()
    # a's effort input comes from b's effort output: b delivers y_e(b) u_f(b), a receives
    # u_e(a) y_f(a)
    sent = np.asarray(values[f"{b}.{fb}"]) * np.asarray(values[f"{b}.{eb}"])
    received = np.asarray(values[f"{a}.{ea}"]) * np.asarray(values[f"{a}.{fa}"])
    power = sent - received
    t = np.asarray(times, dtype=float)
    out = np.zeros_like(t)
    out[1:] = np.cumsum(np.diff(t) * (power[1:] + power[:-1]) / 2)
    return out


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
             atol: float | None = None) -> Result:
    """Run the scenario with libcosim's ECCO algorithm (initial step ``step``); every
    recorded variable and the bond's variables at every macro step, and the interface
    energy residual."""
    from fmpy import read_model_description
    from libcosimpy.CosimAlgorithm import CosimAlgorithm, EccoParams
    from libcosimpy.CosimExecution import CosimExecution, get_last_error_message
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    if len(scenario.power_bonds) != 2:
        raise CosimError(f"{scenario.name}: ECCO needs a [power_bonds] table (an effort input "
                         "and a flow output of two instances)")
    h = float(step or scenario.step)
    t_end = float(t_end or scenario.t_end)
    descriptions = {i.name: read_model_description(str(fmus[i.name])) for i in scenario.instances}
    check_variables(scenario, descriptions)
    vr = {inst: {v.name: v.valueReference for v in md.modelVariables}
          for inst, md in descriptions.items()}
    unit = {inst: {v.name: v.unit or "" for v in md.modelVariables}
            for inst, md in descriptions.items()}
    log_output_level(CosimLogLevel.WARNING)
    tol = rtol or ECCO_RTOL
    algorithm = CosimAlgorithm.create_ecco_algorithm(EccoParams(
        step_size=h, min_step_size=MIN_STEP_FACTOR * h, max_step_size=MAX_STEP_FACTOR * h,
        rel_tolerance=tol, abs_tolerance=atol or ECCO_ATOL, min_change_rate=MIN_CHANGE,
        max_change_rate=MAX_CHANGE))
    execution = CosimExecution.from_algorithm(algorithm)
    execution, index = _build_from_description(bond_first(scenario), fmus,
                                               _ns(h, "the step"), vr, execution=execution)
    (a, (ea, fa)), (b, (eb, fb)) = scenario.power_bonds.items()
    if algorithm.add_power_bond(index[a], vr[a][fa], vr[a][ea],
                                index[b], vr[b][fb], vr[b][eb]) != 0:
        raise CosimError(f"libcosim refused the power bond: {get_last_error_message()}")
    names = list(dict.fromkeys(list(record if record is not None else scenario.recorded())
                               + bond_variables(scenario)))
    times, columns = _simulate(execution, index, vr, names, t_end,
                               int(10 * t_end / (MIN_STEP_FACTOR * h)) + 16)
    columns[RESIDUAL] = energy_residual(times, columns, scenario)
    n = len(times)
    del execution
    out_names = names + [RESIDUAL]
    units = {nm: unit[nm.split(".", 1)[0]].get(nm.split(".", 1)[1], "") for nm in names}
    units[RESIDUAL] = "J"
    return Result(time=times, names=out_names,
                  values=np.column_stack([columns[k] for k in out_names]), units=units,
                  method="libcosim ecco", stats={"steps": int(n - 1),
                                                 "mean_step": float(times[-1] / max(n - 1, 1))})
