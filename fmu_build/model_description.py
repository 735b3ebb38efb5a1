"""Write the FMI 2.0 ``modelDescription.xml`` of an FMU from its variable table.

Everything comes from the ``Variable`` table the runtime also loads, so value references,
causalities and start values cannot disagree between the XML and the running FMU.
Written as FMI 2.0 section 2.2 asks: UnitDefinitions with BaseUnit exponents for every
unit used, LogCategories, DefaultExperiment, ModelVariables, and a ModelStructure whose
Outputs list every output (``dependencies`` when declared, ``""`` meaning none) and whose
InitialUnknowns list every output with initial approx or calculated and every calculated
parameter (section 2.2.8).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from xml.etree import ElementTree as ET

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


class ModelDescriptionError(ValueError):
    """A table or setting the model description cannot express (the message says why)."""


@dataclass(frozen=True)
class Capabilities:
    """The CoSimulation element's flags (FMI 2.0 section 4.3.1).

    canRunAsynchronuously is always false: the runtime steps synchronously, and
    fmi2CancelStep returns fmi2Error.
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


def model_description(table: VariableTable, model_name: str, model_identifier: str, guid: str, *,
                      info: ModelInfo = ModelInfo(), capabilities: Capabilities = Capabilities(),
                      default_experiment: DefaultExperiment | None = None,
                      log_categories: dict[str, str] | None = None) -> str:
    """The modelDescription.xml text (UTF-8 declaration included)."""
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": model_name, "guid": guid, "description": info.description,
        **{k: v for k, v in (("author", info.author), ("version", info.version)) if v},
        "generationTool": info.generation_tool, "variableNamingConvention": "flat"})
    ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": model_identifier, "needsExecutionTool": "false",
        "canHandleVariableCommunicationStepSize":
            _flag(capabilities.can_handle_variable_communication_step_size),
        "canInterpolateInputs": _flag(capabilities.can_interpolate_inputs),
        "maxOutputDerivativeOrder": str(capabilities.max_output_derivative_order),
        "canRunAsynchronuously": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true",
        "canGetAndSetFMUstate": _flag(capabilities.can_get_and_set_fmu_state),
        "canSerializeFMUstate": _flag(capabilities.can_serialize_fmu_state),
        "providesDirectionalDerivative": _flag(capabilities.provides_directional_derivative)})
    _unit_definitions(root, table)
    categories = ET.SubElement(root, "LogCategories")
    for name, text in {**STANDARD_CATEGORIES, **(log_categories or {})}.items():
        ET.SubElement(categories, "Category", {"name": name, "description": text})
    if default_experiment is not None:
        ET.SubElement(root, "DefaultExperiment", {
            key: _number(float(value)) for key, value in (
                ("startTime", default_experiment.start_time),
                ("stopTime", default_experiment.stop_time),
                ("stepSize", default_experiment.step_size),
                ("tolerance", default_experiment.tolerance)) if value is not None})
    _model_variables(root, table)
    _model_structure(root, table)
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


def _model_variables(root: ET.Element, table: VariableTable) -> None:
    variables = ET.SubElement(root, "ModelVariables")
    for v in table.variables:
        attributes = {"name": v.name, "valueReference": str(v.value_reference),
                      "causality": v.causality, "variability": v.variability}
        if v.initial is not None and v.causality != "input":
            attributes["initial"] = v.initial
        if v.description:
            attributes["description"] = v.description
        element = ET.SubElement(variables, "ScalarVariable", attributes)
        typed = ET.SubElement(element, v.type)
        if v.unit and v.type == "Real":
            typed.set("unit", v.unit)
        if v.start is not None:
            typed.set("start", _start_text(v))


def _model_structure(root: ET.Element, table: VariableTable) -> None:
    index = {v.name: i for i, v in enumerate(table.variables, start=1)}
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [v for v in table.variables if v.causality == "output"]
    initial = [v for v in table.variables
               if (v.causality == "output" and v.initial in ("approx", "calculated"))
               or v.causality == "calculatedParameter"]
    for tag, chosen, attr in (("Outputs", outputs, "dependencies"),
                              ("InitialUnknowns", initial, "initial_dependencies")):
        if not chosen:
            continue
        element = ET.SubElement(structure, tag)
        for v in chosen:
            unknown = ET.SubElement(element, "Unknown", {"index": str(index[v.name])})
            names = getattr(v, attr)
            if names is not None:
                unknown.set("dependencies", " ".join(str(index[n]) for n in sorted(names, key=index.get)))
