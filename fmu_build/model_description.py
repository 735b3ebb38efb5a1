"""Write the ``modelDescription.xml`` of an FMU (FMI 2.0 or 3.0) from its variable table.

Everything comes from the ``Variable`` table the runtime also loads, so value references,
causalities and start values cannot disagree between the XML and the running FMU.
Written as FMI 2.0 section 2.2 (FMI 3.0 section 2.4) asks: UnitDefinitions with BaseUnit
exponents for every unit used, LogCategories, DefaultExperiment, ModelVariables, and a
ModelStructure whose Outputs list every output (``dependencies`` when declared, ``""``
meaning none), whose Derivatives (FMI 3.0: ContinuousStateDerivative) list the state
derivatives (variables with a ``derivative`` that are not inputs) and whose
InitialUnknowns list every output with initial approx or calculated, every calculated
parameter, and the states and state derivatives that are calculated (section 2.2.8).
FMI 2.0 refers to variables by index (from 1), FMI 3.0 by value reference.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from xml.etree import ElementTree as ET

from .runtime.fmi3 import fmi3_text
from .runtime.log import STANDARD_CATEGORIES
from .runtime.variables import Variable, VariableTable

# SI base-unit exponents (FMI 2.0 BaseUnit attributes) of the unit symbols a name may use.
SYMBOLS: dict[str, dict[str, int]] = {
    "1": {}, "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "A": {"A": 1}, "K": {"K": 1},
    "mol": {"mol": 1}, "cd": {"cd": 1}, "rad": {"rad": 1},
    "N": {"kg": 1, "m": 1, "s": -2}, "J": {"kg": 1, "m": 2, "s": -2},
    "W": {"kg": 1, "m": 2, "s": -3}, "Pa": {"kg": 1, "m": -1, "s": -2}, "Hz": {"s": -1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1}, "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
}
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


# FMI 3.0 element name of each table type.
FMI3_ELEMENTS = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}


class ModelDescriptionError(ValueError):
    """A table or setting the model description cannot express (the message says why)."""


@dataclass(frozen=True)
class Capabilities:
    """The CoSimulation element's flags (FMI 2.0 section 4.3.1, FMI 3.0 section 4.4).

    canRunAsynchronuously is always false: the runtime steps synchronously, and
    fmi2CancelStep returns fmi2Error. FMI 3.0: no Event Mode, no intermediate update, no
    early return, no adjoint derivatives; ``can_interpolate_inputs`` becomes derivative
    inputs in the variable table (runtime/fmi3.py) instead of a flag.
    """

    can_handle_variable_communication_step_size: bool = True
    can_interpolate_inputs: bool = False
    max_output_derivative_order: int = 0
    can_get_and_set_fmu_state: bool = True
    can_serialize_fmu_state: bool = True
    provides_directional_derivative: bool = False


@dataclass(frozen=True)
class ModelInfo:
    """The model description's descriptive attributes (FMI 2.0 section 2.2.1)."""

    description: str = ""
    author: str = ""
    version: str = ""
    generation_tool: str = "mbdfmu"


@dataclass(frozen=True)
class DefaultExperiment:
    """Suggested run settings (seconds; tolerance relative); None leaves one out."""

    start_time: float | None = 0.0
    stop_time: float | None = None
    step_size: float | None = None
    tolerance: float | None = None


def unit_exponents(unit: str) -> dict[str, int]:
    """SI base-unit exponents of a unit name such as ``N.m``, ``m/s2``, ``kg.m2`` or
    ``m3/(s.Pa)``."""
    exponents: dict[str, int] = {}
    numerator, _, denominator = unit.partition("/")
    if denominator.startswith("(") and denominator.endswith(")"):
        denominator = denominator[1:-1]
    for part, sign in ((numerator, 1), (denominator, -1)):
        for token in filter(None, part.split(".")):
            match = re.fullmatch(r"([A-Za-z]+|1)(-?\d*)", token)
            if not match or match.group(1) not in SYMBOLS:
                raise ModelDescriptionError(f'unit "{unit}": unknown symbol "{token}" '
                                            f"(known: {', '.join(SYMBOLS)})")
            for base, e in SYMBOLS[match.group(1)].items():
                exponents[base] = exponents.get(base, 0) + sign * e * int(match.group(2) or 1)
    return {k: v for k, v in exponents.items() if v}


def _flag(value: bool) -> str:
    return "true" if value else "false"


def _number(value) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


def _start_text(v: Variable) -> str:
    if v.type == "Boolean":
        return _flag(v.start)
    return _number(v.start) if v.type != "String" else v.start


def _co_simulation(capabilities: Capabilities, model_identifier: str, fmi_version: int) -> dict:
    c = capabilities
    common = {"modelIdentifier": model_identifier, "needsExecutionTool": "false",
              "canBeInstantiatedOnlyOncePerProcess": "false",
              "canHandleVariableCommunicationStepSize":
                  _flag(c.can_handle_variable_communication_step_size),
              "maxOutputDerivativeOrder": str(c.max_output_derivative_order)}
    if fmi_version == 3:
        return {**common, "canGetAndSetFMUState": _flag(c.can_get_and_set_fmu_state),
                "canSerializeFMUState": _flag(c.can_serialize_fmu_state),
                "providesDirectionalDerivatives": _flag(c.provides_directional_derivative),
                "providesAdjointDerivatives": "false", "providesPerElementDependencies": "false",
                "hasEventMode": "false", "providesIntermediateUpdate": "false",
                "mightReturnEarlyFromDoStep": "false",
                "canReturnEarlyAfterIntermediateUpdate": "false"}
    return {**common, "canInterpolateInputs": _flag(c.can_interpolate_inputs),
            "canRunAsynchronuously": "false", "canNotUseMemoryManagementFunctions": "true",
            "canGetAndSetFMUstate": _flag(c.can_get_and_set_fmu_state),
            "canSerializeFMUstate": _flag(c.can_serialize_fmu_state),
            "providesDirectionalDerivative": _flag(c.provides_directional_derivative)}


def model_description(table: VariableTable, model_name: str, model_identifier: str, guid: str, *,
                      info: ModelInfo = ModelInfo(), capabilities: Capabilities = Capabilities(),
                      default_experiment: DefaultExperiment | None = None,
                      log_categories: dict[str, str] | None = None, fmi_version: int = 2,
                      annotations: dict[str, ET.Element] | None = None) -> str:
    """The modelDescription.xml text (UTF-8 declaration included) of FMI ``fmi_version``
    (2 or 3). ``guid`` is FMI 3.0's instantiationToken. ``annotations``: tool name -> the
    element to write under it (FMI 2.0 VendorAnnotations/Tool, FMI 3.0
    Annotations/Annotation of that type)."""
    if fmi_version not in (2, 3):
        raise ModelDescriptionError(f"FMI version {fmi_version!r}: mbdfmu writes 2.0 and 3.0")
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": f"{fmi_version}.0", "modelName": model_name,
        "instantiationToken" if fmi_version == 3 else "guid": guid,
        "description": info.description,
        **{k: v for k, v in (("author", info.author), ("version", info.version)) if v},
        "generationTool": info.generation_tool, "variableNamingConvention": "flat"})
    ET.SubElement(root, "CoSimulation", _co_simulation(capabilities, model_identifier,
                                                        fmi_version))
    _unit_definitions(root, table)
    categories = ET.SubElement(root, "LogCategories")
    for name, text in {**STANDARD_CATEGORIES, **(log_categories or {})}.items():
        ET.SubElement(categories, "Category", {"name": name, "description": text if fmi_version == 2
                                               else fmi3_text(text)})
    if default_experiment is not None:
        ET.SubElement(root, "DefaultExperiment", {
            key: _number(float(value)) for key, value in (
                ("startTime", default_experiment.start_time),
                ("stopTime", default_experiment.stop_time),
                ("stepSize", default_experiment.step_size),
                ("tolerance", default_experiment.tolerance)) if value is not None})
    if annotations and fmi_version == 2:
        vendor = ET.SubElement(root, "VendorAnnotations")
        for tool, element in annotations.items():
            ET.SubElement(vendor, "Tool", {"name": tool}).append(element)
    if fmi_version == 3:
        _model_variables_3(root, table)
    else:
        _model_variables(root, table)
    _model_structure(root, table, fmi_version)
    if annotations and fmi_version == 3:
        block = ET.SubElement(root, "Annotations")
        for tool, element in annotations.items():
            ET.SubElement(block, "Annotation", {"type": tool}).append(element)
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _unit_definitions(root: ET.Element, table: VariableTable) -> None:
    units = sorted({v.unit for v in table.variables if v.unit})
    if not units:
        return
    definitions = ET.SubElement(root, "UnitDefinitions")
    for unit in units:
        exponents = unit_exponents(unit)
        element = ET.SubElement(definitions, "Unit", {"name": unit})
        ET.SubElement(element, "BaseUnit", {b: str(exponents[b]) for b in BASE_UNITS if b in exponents})


def _attributes(v: Variable) -> dict[str, str]:
    attributes = {"name": v.name, "valueReference": str(v.value_reference),
                  "causality": v.causality, "variability": v.variability}
    if v.initial is not None and v.causality != "input":
        attributes["initial"] = v.initial
    if v.description:
        attributes["description"] = v.description
    return attributes


def _model_variables_3(root: ET.Element, table: VariableTable) -> None:
    variables = ET.SubElement(root, "ModelVariables")
    for v in table.variables:
        attributes = _attributes(v)
        if v.unit and v.type == "Real":
            attributes["unit"] = v.unit
        if v.derivative is not None:
            attributes["derivative"] = str(table.by_name[v.derivative].value_reference)
        if v.start is not None and v.type != "String":
            attributes["start"] = _start_text(v)
        element = ET.SubElement(variables, FMI3_ELEMENTS[v.type], attributes)
        if v.start is not None and v.type == "String":
            ET.SubElement(element, "Start", {"value": v.start})


def _model_variables(root: ET.Element, table: VariableTable) -> None:
    index = {v.name: i for i, v in enumerate(table.variables, start=1)}
    variables = ET.SubElement(root, "ModelVariables")
    for v in table.variables:
        element = ET.SubElement(variables, "ScalarVariable", _attributes(v))
        typed = ET.SubElement(element, v.type)
        if v.unit and v.type == "Real":
            typed.set("unit", v.unit)
        if v.derivative is not None:
            typed.set("derivative", str(index[v.derivative]))
        if v.start is not None:
            typed.set("start", _start_text(v))


def state_derivatives(table: VariableTable) -> list[Variable]:
    """The state derivatives (variables with a ``derivative`` that are not inputs)."""
    return [v for v in table.variables if v.derivative is not None and v.causality != "input"]


def _initial_unknowns(table: VariableTable) -> list[Variable]:
    derivatives = state_derivatives(table)
    exposed = {v.name for v in derivatives} | {v.derivative for v in derivatives}
    return [v for v in table.variables
            if (v.causality == "output" and v.initial in ("approx", "calculated"))
            or v.causality == "calculatedParameter"
            or (v.name in exposed and v.initial in ("approx", "calculated"))]


def _model_structure(root: ET.Element, table: VariableTable, fmi_version: int) -> None:
    """FMI 2.0: Outputs, Derivatives, InitialUnknowns of Unknown elements by index; FMI 3.0:
    Output, ContinuousStateDerivative, InitialUnknown elements by value reference."""
    if fmi_version == 3:
        ref = {v.name: v.value_reference for v in table.variables}
    else:
        ref = {v.name: i for i, v in enumerate(table.variables, start=1)}
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [v for v in table.variables if v.causality == "output"]
    groups = (("Outputs", "Output", outputs, "dependencies"),
              ("Derivatives", "ContinuousStateDerivative", state_derivatives(table),
               "dependencies"),
              ("InitialUnknowns", "InitialUnknown", _initial_unknowns(table),
               "initial_dependencies"))
    for tag2, tag3, chosen, attr in groups:
        if not chosen:
            continue
        parent = structure if fmi_version == 3 else ET.SubElement(structure, tag2)
        for v in chosen:
            key = "valueReference" if fmi_version == 3 else "index"
            unknown = ET.SubElement(parent, tag3 if fmi_version == 3 else "Unknown",
                                    {key: str(ref[v.name])})
            names = getattr(v, attr)
            if names is not None:
                unknown.set("dependencies", " ".join(str(ref[n]) for n in sorted(names, key=ref.get)))
