"""A scenario in OSP libcosim (C++ master) through libcosimpy, from the same description.

libcosim's fixed-step algorithm is Jacobi: every slave steps from t to t + h on the inputs
of time t, then the outputs are passed on. Before the first step it runs the slaves'
initialization mode and passes outputs to inputs there (several rounds), so connected
inputs start at the upstream outputs of t = 0, as the fmpy master's ``start="exchange"``.
Times are integers in nanoseconds: the step must be a whole number of nanoseconds.

The slaves run in-process (``CosimLocalSlave``): mbdfmu FMUs use the host's Python.

An execution is made and run with the calling thread held to one core
(``threads.one_core``): libcosim's worker threads inherit that.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..result import Result
from .scenario import Scenario, check_variables
from .settings import CosimError, fixed_steps
from .threads import one_core

NS = 1_000_000_000


def _ns(seconds: float, what: str) -> int:
    ns = round(seconds * NS)
    if ns <= 0 or abs(ns - seconds * NS) > 1e-6 * max(1.0, seconds * NS):
        raise CosimError(f"libcosim counts time in whole nanoseconds: {what} {seconds!r} s is not")
    return ns


def _build_from_description(scenario: Scenario, fmus, h_ns: int, vr: dict, execution=None):
    """An execution (by default fixed-step, ``h_ns``) with one local slave per instance,
    its start values and connections."""
    from libcosimpy import CosimExecution as cx
    from libcosimpy.CosimExecution import get_last_error_message
    from libcosimpy.CosimSlave import CosimLocalSlave

    if execution is None:
        execution = cx.CosimExecution.from_step_size(step_size=h_ns)
    index = {}
    for inst in scenario.instances:
        slave = CosimLocalSlave(fmu_path=str(fmus[inst.name]), instance_name=inst.name)
        index[inst.name] = execution.add_local_slave(slave)
        if index[inst.name] < 0:
            raise CosimError(f"libcosim cannot load {fmus[inst.name]}: {get_last_error_message()}")
    for key, value in scenario.parameters.items():
        inst, var = key.split(".", 1)
        if not execution.real_initial_value(index[inst], vr[inst][var], float(value)):
            raise CosimError(f'libcosim refused the start value of "{key}": '
                             f"{get_last_error_message()}")
    for c in scenario.connections:
        status = execution.connect_real_variables(
            index[c.source_instance], vr[c.source_instance][c.source_variable],
            index[c.target_instance], vr[c.target_instance][c.target_variable])
        if status != 0:
            raise CosimError(f'libcosim cannot connect "{c.source}" -> "{c.target}": '
                             f"{get_last_error_message()}")
    return execution, index


def _build_from_ssp(scenario: Scenario, ssp_path, h_ns: int):
    from libcosimpy import CosimExecution as cx
    from libcosimpy.CosimExecution import get_last_error_message

    try:
        execution = cx.CosimExecution.from_ssp_file(str(ssp_path), step_size=h_ns)
    except AssertionError:
        raise CosimError(f"libcosim cannot load {ssp_path}: {get_last_error_message()}") from None
    return execution, {i.name: execution.slave_index_from_instance_name(i.name)
                       for i in scenario.instances}


def _record(execution, index, vr, names: list[str], n: int) -> tuple[np.ndarray, np.ndarray]:
    """Run n steps (plus one: the observer keeps t_k's sample once step k + 1 has run) and
    return the times (ns) and the samples of ``names`` at t_0 .. t_n."""
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import get_last_error_message
    from libcosimpy.CosimObserver import CosimObserver

    series = CosimObserver.create_time_series(buffer_size=n + 16)
    execution.add_observer(series)
    for name in names:
        inst, var = name.split(".", 1)
        series.start_time_series(index[inst], value_reference=vr[inst][var],
                                 variable_type=CosimVariableType.REAL)
    if not execution.step(n + 1):
        raise CosimError(f"libcosim stopped at t = {execution.status().current_time / NS:g} s: "
                         f"{get_last_error_message()}")
    columns, times = [], None
    for name in names:
        inst, var = name.split(".", 1)
        t, _, values = series.time_series_real_samples(index[inst], vr[inst][var],
                                                       from_step=0, sample_count=n + 2)
        # (libcosimpy returns at most sample_count - 1 samples)
        t, values = t[:n + 1], values[:n + 1]
        if len(values) != n + 1:
            raise CosimError(f'libcosim recorded {len(values)} samples of "{name}", '
                             f"expected {n + 1}")
        times = np.asarray(t, dtype=np.int64)
        columns.append(np.asarray(values, dtype=float))
    return times, np.column_stack(columns)


def run_libcosim(scenario: Scenario, fmus: dict[str, Path], step: float | None = None,
                 t_end: float | None = None, record: list[str] | None = None,
                 algorithm: str | None = None, ssp_path: str | Path | None = None) -> Result:
    """Run the scenario in libcosim's fixed-step (Jacobi) algorithm; every recorded
    variable at every communication point, t = 0 included.

    The system is built from the description (slaves, start values, connections through
    libcosimpy's API), or, with ``ssp_path``, loaded by libcosim from that SSP file (as
    written by ``ssp_runner.export_ssp``: libcosim reads its parameter binding and
    connections).
    """
    from fmpy import read_model_description
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    h_ns = _ns(float(step or scenario.step), "the step")   # first: libcosim's own limit
    h, t_end, n = fixed_steps(scenario, step, t_end, algorithm, "libcosim's fixed-step algorithm")
    end_ns = _ns(t_end, "t_end")
    if n * h_ns != end_ns:
        raise CosimError(f"t_end {t_end:g} s is not a whole number of steps {h:g} s in ns")
    descriptions = {i.name: read_model_description(str(fmus[i.name])) for i in scenario.instances}
    check_variables(scenario, descriptions)
    vr = {inst: {v.name: v.valueReference for v in md.modelVariables}
          for inst, md in descriptions.items()}
    unit = {inst: {v.name: v.unit or "" for v in md.modelVariables}
            for inst, md in descriptions.items()}
    names = list(record if record is not None else scenario.recorded())
    log_output_level(CosimLogLevel.WARNING)  # its debug messages would flood the console
    with one_core():
        execution, index = (_build_from_ssp(scenario, ssp_path, h_ns) if ssp_path is not None
                            else _build_from_description(scenario, fmus, h_ns, vr))
        times, values = _record(execution, index, vr, names, n)
        del execution  # frees the slaves
    return Result(time=times * (1.0 / NS), names=names, values=values,
                  units={nm: unit[nm.split(".", 1)[0]][nm.split(".", 1)[1]] for nm in names},
                  method="libcosim jacobi" + (" (from the SSP)" if ssp_path else ""),
                  stats={"steps": int(n)})
