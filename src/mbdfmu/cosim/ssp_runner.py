"""A scenario as an SSP 1.0 file (``.ssp``), run with fmpy's SSP runner.

``export_ssp`` writes a zip holding ``SystemStructure.ssd`` and the FMUs under
``resources/``. The system description carries

* one component per instance, with a connector for each connected input and for each
  output the scenario records (fmpy's runner records connectors only);
* the connections;
* the scenario's start values as each component's parameter binding (inline
  ``ssv:ParameterSet``, all named ``PARAMETER_SET``; OSP libcosim reads component bindings,
  not system-level ones);
* the units of the connectors, a DefaultExperiment (0 to ``t_end``) and, for OSP libcosim,
  the communication step as its ``FixedStepAlgorithm`` annotation.

fmpy's runner (``fmpy.ssp.simulation.simulate_ssp``, fmpy 0.3.32) is a fixed-step Jacobi
master with three habits this module accounts for:

* its connectors start at 0.0, so every connected input sees 0.0 over the first step. The
  hydraulic crane cannot start that way (a cylinder of length 0 is outside its stroke: the
  hydraulics discard the first step), and the other scenarios start with a jolt. ``run_ssp``
  therefore starts the way libcosim and the fmpy master do (``start="exchange"``): while
  the runner instantiates the FMUs it passes outputs to inputs, as many rounds as there are
  components, after the last one is initialized (``_exchange_at_start`` wraps the runner's
  ``instantiate_fmu`` for the duration of the call; nothing else of the runner changes).
  ``start="zero"`` runs it untouched; the fmpy master's ``start="zero"`` reproduces that;
* each result row is stamped with the start of its step while holding the outputs of its
  end, so ``run_ssp`` re-stamps rows with the end times ``k h``;
* it never reads the SSD's parameter bindings: ``run_ssp`` reads them from the SSP and passes
  them on.
"""

from __future__ import annotations

import zipfile
from contextlib import contextmanager, nullcontext
from pathlib import Path
from xml.etree.ElementTree import Element, SubElement, indent, register_namespace, tostring

import numpy as np

from .. import __version__
from ..result import Result
from .settings import CosimError, fixed_steps
from .scenario import Scenario, check_variables

NS = {
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
    "osp": "https://opensimulationplatform.com/SSP/OSPAnnotations",
}
FMU_TYPE = "application/x-fmu-sharedlibrary"
# Every component's start values form a parameter set of this one name: Ecos applies the
# sets of the name it is given across all components, fmpy and libcosim read every set.
PARAMETER_SET = "start values"
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


def _q(prefix: str, tag: str) -> str:
    return f"{{{NS[prefix]}}}{tag}"


def _number(value: float) -> str:
    return repr(float(value))


def _component(elements, scenario: Scenario, inst, md, record: list[str], units: dict) -> None:
    """One instance as an SSD component: its connectors (with units, collected in ``units``)
    and its start values as a parameter binding named PARAMETER_SET."""
    variables = {v.name: v for v in md.modelVariables}
    definitions = {u.name: u for u in md.unitDefinitions}
    comp = SubElement(elements, _q("ssd", "Component"),
                      {"name": inst.name, "type": FMU_TYPE,
                       "source": f"resources/{inst.source.stem}.fmu"})
    connectors = SubElement(comp, _q("ssd", "Connectors"))
    start_values = scenario.instance_parameters(inst.name)
    if start_values:
        binding = SubElement(SubElement(comp, _q("ssd", "ParameterBindings")),
                             _q("ssd", "ParameterBinding"))
        pset = SubElement(SubElement(binding, _q("ssd", "ParameterValues")),
                          _q("ssv", "ParameterSet"), {"version": "1.0", "name": PARAMETER_SET})
        params = SubElement(pset, _q("ssv", "Parameters"))
        for name, value in start_values.items():
            p = SubElement(params, _q("ssv", "Parameter"), {"name": name})
            SubElement(p, _q("ssv", "Real"), {"value": _number(value)})
    inputs = [c.target_variable for c in scenario.connections if c.target_instance == inst.name]
    outputs = [r.split(".", 1)[1] for r in record if r.split(".", 1)[0] == inst.name]
    for kind, names in (("input", inputs), ("output", outputs)):
        for name in dict.fromkeys(names):
            con = SubElement(connectors, _q("ssd", "Connector"), {"name": name, "kind": kind})
            real = SubElement(con, _q("ssc", "Real"))
            unit = variables[name].unit
            if unit:
                real.set("unit", unit)
                if unit in definitions:
                    units.setdefault(unit, definitions[unit])


def _units_and_experiment(root, units: dict, step: float, t_end: float) -> None:
    if units:
        ssd_units = SubElement(root, _q("ssd", "Units"))
        for name, u in sorted(units.items()):
            unit = SubElement(ssd_units, _q("ssc", "Unit"), {"name": name})
            base = {k: str(getattr(u.baseUnit, k)) for k in BASE_UNITS
                    if u.baseUnit is not None and getattr(u.baseUnit, k, 0)}
            SubElement(unit, _q("ssc", "BaseUnit"), base)
    experiment = SubElement(root, _q("ssd", "DefaultExperiment"),
                            {"startTime": "0.0", "stopTime": _number(t_end)})
    annotation = SubElement(SubElement(experiment, _q("ssd", "Annotations")),
                            _q("ssc", "Annotation"), {"type": "com.opensimulationplatform"})
    algorithm = SubElement(annotation, _q("osp", "Algorithm"))
    SubElement(algorithm, _q("osp", "FixedStepAlgorithm"), {"baseStepSize": _number(step)})


def system_structure(scenario: Scenario, descriptions: dict, step: float, t_end: float,
                     record: list[str]) -> bytes:
    """The ``SystemStructure.ssd`` of a scenario (``descriptions``: fmpy model descriptions
    by instance; sources under ``resources/<source stem>.fmu``)."""
    for prefix, uri in NS.items():
        register_namespace(prefix, uri)
    root = Element(_q("ssd", "SystemStructureDescription"),
                   {"version": "1.0", "name": scenario.name,
                    "generationTool": f"mbdfmu {__version__}"})
    system = SubElement(root, _q("ssd", "System"), {"name": scenario.name})
    if scenario.description:
        system.set("description", scenario.description)
    elements = SubElement(system, _q("ssd", "Elements"))
    units: dict[str, object] = {}
    for inst in scenario.instances:
        _component(elements, scenario, inst, descriptions[inst.name], record, units)
    if scenario.connections:
        connections = SubElement(system, _q("ssd", "Connections"))
        for c in scenario.connections:
            SubElement(connections, _q("ssd", "Connection"),
                       {"startElement": c.source_instance, "startConnector": c.source_variable,
                        "endElement": c.target_instance, "endConnector": c.target_variable})
    _units_and_experiment(root, units, step, t_end)
    indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def export_ssp(scenario: Scenario, fmus: dict[str, Path], path: str | Path,
               step: float | None = None, t_end: float | None = None,
               record: list[str] | None = None) -> Path:
    """Write the scenario as an SSP file holding its FMUs; returns the path."""
    from fmpy import read_model_description

    descriptions = {i.name: read_model_description(str(fmus[i.name])) for i in scenario.instances}
    check_variables(scenario, descriptions)
    record = list(record if record is not None else scenario.recorded())
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ssd = system_structure(scenario, descriptions, float(step or scenario.step),
                           float(t_end or scenario.t_end), record)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("SystemStructure.ssd", ssd)
        for inst in scenario.instances:
            name = f"resources/{inst.source.stem}.fmu"
            if name not in z.namelist():
                z.write(fmus[inst.name], name)
    return path


def start_values(path: str | Path):
    """The SSP's start values as one fmpy ``ParameterSet`` named ``<component>.<variable>``
    (the runner's ``parameter_set``: it reads none of the SSD's bindings itself)."""
    from fmpy.ssp.ssd import Parameter, ParameterSet, find_components, read_ssd

    merged = ParameterSet(name="start values")
    for component in find_components(read_ssd(str(path)).system):
        for binding in component.parameterBindings:
            for pset in binding.parameterValues:
                for p in pset.parameters:
                    merged.parameters.append(Parameter(name=f"{component.name}.{p.name}",
                                                       type=p.type, value=p.value))
    return merged


@contextmanager
def _exchange_at_start():
    """Make fmpy's SSP runner pass outputs to inputs once every FMU is initialized (instead
    of starting every connector at 0.0): wraps its ``instantiate_fmu`` while active."""
    import fmpy.ssp.simulation as runner
    from fmpy.ssp.ssd import find_components, get_connections

    original = runner.instantiate_fmu

    def instantiate(component, *args, **kwargs):
        original(component, *args, **kwargs)
        root = component.parent
        while root.parent is not None:
            root = root.parent
        components = find_components(root)
        if not all(hasattr(c, "fmu") for c in components):
            return
        connections = get_connections(root)
        for _ in components:  # enough rounds for any chain of direct feedthrough
            for c in components:
                for con in c.connectors:
                    if con.kind == "output":
                        con.value = runner.get_value(c, con.name)
            for start, end in connections:
                end.value = start.value
            for c in components:
                for con in c.connectors:
                    if con.kind == "input":
                        runner.set_value(c, con.name, con.value)

    runner.instantiate_fmu = instantiate
    try:
        yield
    finally:
        runner.instantiate_fmu = original


def run_ssp(scenario: Scenario, fmus: dict[str, Path], ssp_path: str | Path,
            step: float | None = None, t_end: float | None = None,
            record: list[str] | None = None, algorithm: str | None = None,
            start: str = "exchange") -> Result:
    """Export the scenario to ``ssp_path`` and run it with ``fmpy.ssp.simulate_ssp``
    (``start``: "exchange" or "zero", see the module docstring).

    Rows are the recorded outputs at ``h, 2h, ..., t_end`` (the runner keeps no row at 0).
    """
    from fmpy.ssp.simulation import simulate_ssp

    h, t_end, n = fixed_steps(scenario, step, t_end, algorithm, "fmpy's SSP runner")
    record = list(record if record is not None else scenario.recorded())
    path = export_ssp(scenario, fmus, ssp_path, h, t_end, record)
    parameters = start_values(path)
    # The runner steps while its accumulated time is below stop_time: half a step short of
    # t_end gives exactly n steps whatever the rounding of the sum.
    if start not in ("exchange", "zero"):
        raise CosimError(f'start "{start}" is not "exchange" or "zero"')
    try:
        with _exchange_at_start() if start == "exchange" else nullcontext():
            table = simulate_ssp(str(path), start_time=0.0, stop_time=(n - 0.5) * h,
                                 step_size=h, parameter_set=parameters)
    except Exception as exc:  # noqa: BLE001 - fmpy raises plain exceptions (a refused doStep)
        raise CosimError(f"fmpy's SSP runner failed: {type(exc).__name__}: {exc}") from None
    if len(table) != n:
        raise CosimError(f"fmpy's SSP runner took {len(table)} steps, expected {n}")
    units = {}
    for inst in scenario.instances:
        from fmpy import read_model_description

        md = read_model_description(str(fmus[inst.name]))
        units.update({f"{inst.name}.{v.name}": v.unit or "" for v in md.modelVariables})
    values = np.column_stack([np.asarray(table[name], dtype=float) for name in record])
    if not np.all(np.isfinite(values)):
        bad = [r for r, col in zip(record, values.T) if not np.all(np.isfinite(col))]
        raise CosimError(f"fmpy's SSP runner: {', '.join(bad)} became non-finite")
    return Result(time=np.arange(1, n + 1) * h, names=record, values=values,
                  units={r: units.get(r, "") for r in record},
                  method=f"fmpy SSP runner (jacobi, {start} start)",
                  stats={"steps": n})
