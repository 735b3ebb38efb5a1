"""The variable table: the one source of an FMU's value references, types and rules.

The builder writes the table into ``resources/mbdfmu.json`` (``Variable.to_dict``) and
``model_description.py`` turns the same table into the model description, so the XML
and the running FMU cannot disagree on a value reference.

Attribute names and allowed combinations are those of FMI 2.0 section 2.2.7; an FMI 3.0
FMU's table is the same with FMI 3.0's type names as aliases (``Float64`` is ``Real``,
``Int32`` is ``Integer``), its independent variable (``time``) and, for inputs a model can
follow as polynomials, derivative inputs (``derivative`` names the variable a variable is
the time derivative of, as FMI's ``derivative`` attribute).
"""

from __future__ import annotations

from dataclasses import dataclass, field

TYPES = ("Real", "Integer", "Boolean", "String")
CAUSALITIES = ("parameter", "calculatedParameter", "input", "output", "local", "independent")
# FMI 3.0 type names of the table's types; FMI 3.0 types the runtime has no variables of.
FMI3_TYPES = {"Float64": "Real", "Int32": "Integer", "Boolean": "Boolean", "String": "String"}
FMI3_EMPTY = ("Float32", "Int8", "UInt8", "Int16", "UInt16", "UInt32", "Int64", "UInt64",
              "Binary", "Clock")
VARIABILITIES = ("constant", "fixed", "tunable", "discrete", "continuous")
INITIALS = ("exact", "approx", "calculated")
# FMI 2.0 fmi2Integer is a C int: 32 bits.
INT32_MIN, INT32_MAX = -2**31, 2**31 - 1
# The Python type a value of each FMI type is held in.
PYTHON_TYPES = {"Real": float, "Integer": int, "Boolean": bool, "String": str}
# The FMI default of `initial` for each causality (FMI 2.0 table in section 2.2.7).
DEFAULT_INITIAL = {"parameter": "exact", "calculatedParameter": "calculated",
                   "output": "calculated", "local": "calculated", "input": None,
                   "independent": None}


class VariableError(ValueError):
    """A variable declaration that FMI 2.0 does not allow (the message names it)."""


@dataclass(frozen=True)
class Variable:
    """One FMI scalar variable.

    ``start`` is in the variable's ``unit`` (SI names such as ``"m"``, ``"N.m"``).
    ``dependencies`` (outputs and state derivatives) names the knowns (inputs, exposed
    states) the variable depends on directly within one communication point: ``()``
    means none (written as ``dependencies=""``), ``None`` means "all" (left out). ``initial_dependencies`` is the same
    for the output's value in Initialization Mode (knowns: inputs and exact parameters).
    ``derivative`` names the variable this one is the time derivative of (a state's
    derivative, or an FMI 3.0 derivative input).
    """

    name: str
    value_reference: int
    type: str = "Real"
    causality: str = "local"
    variability: str | None = None
    initial: str | None = None
    start: float | int | bool | str | None = None
    unit: str | None = None
    description: str = ""
    dependencies: tuple[str, ...] | None = None
    initial_dependencies: tuple[str, ...] | None = None
    derivative: str | None = None

    def __post_init__(self):
        if self.variability is None:
            default = "continuous" if self.type == "Real" else "discrete"
            object.__setattr__(self, "variability",
                               "fixed" if self.causality == "parameter" else default)
        if self.initial is None:
            object.__setattr__(self, "initial", DEFAULT_INITIAL.get(self.causality))
        for attr in ("dependencies", "initial_dependencies"):
            if getattr(self, attr) is not None:
                object.__setattr__(self, attr, tuple(getattr(self, attr)))
        problem = _declaration_problem(self)
        if problem:
            raise VariableError(f'variable "{self.name}": {problem}')

    @property
    def has_start(self) -> bool:
        """True when FMI requires (and this variable carries) a start value."""
        return self.causality == "input" or self.initial in ("exact", "approx")

    def to_dict(self) -> dict:
        """The JSON form stored in the FMU's config (``derivative`` only when set)."""
        return {k: (list(v) if isinstance(v, tuple) else v)
                for k, v in self.__dict__.items() if k != "derivative" or v is not None}

    @classmethod
    def from_dict(cls, data: dict) -> "Variable":
        """Inverse of ``to_dict``."""
        return cls(**data)


def _declaration_problem(v: Variable) -> str | None:
    """Why ``v`` is not a legal FMI 2.0 co-simulation variable, or None."""
    if not isinstance(v.name, str) or not v.name:
        return "the name must be a non-empty string"
    if not isinstance(v.value_reference, int) or not 0 <= v.value_reference <= 2**32 - 1:
        return f"value reference {v.value_reference!r} is not a 32-bit unsigned integer"
    if v.type not in TYPES or v.causality not in CAUSALITIES:
        return f"type {v.type!r} / causality {v.causality!r} not one of {TYPES} / {CAUSALITIES}"
    if v.variability not in VARIABILITIES or v.initial not in INITIALS + (None,):
        return f"variability {v.variability!r} or initial {v.initial!r} is not an FMI value"
    if v.causality == "independent" and (v.type != "Real" or v.variability != "continuous"
                                         or v.start is not None):
        return "the independent variable is a continuous Real without a start value"
    if v.variability == "continuous" and v.type != "Real":
        return "only Real variables can be continuous"
    if v.causality in ("parameter", "calculatedParameter") and v.variability not in ("fixed", "tunable"):
        return f"a {v.causality} must be fixed or tunable, not {v.variability}"
    if v.variability == "constant" and v.causality not in ("output", "local"):
        return "a constant must be an output or a local"
    if v.causality == "input" and v.initial is not None:
        return "an input has no initial attribute (its start value is required)"
    if v.derivative is not None and (v.type != "Real" or v.derivative == v.name):
        return "only a Real variable can be the derivative of another"
    if v.has_start and v.start is None:
        return f"a {v.causality} with initial={v.initial} needs a start value"
    if not v.has_start and v.start is not None:
        return f"initial={v.initial} does not allow a start value"
    if v.causality != "output" and v.initial_dependencies is not None:
        return "only outputs have initial dependencies"
    if v.causality != "output" and v.derivative is None and v.dependencies is not None:
        return "only outputs and state derivatives have dependencies"
    return None if v.start is None else value_problem(v, v.start)


def value_problem(v: Variable, value) -> str | None:
    """Why ``value`` cannot be a value of ``v`` (wrong Python type or range), or None."""
    kind = PYTHON_TYPES[v.type]
    if kind is float:
        ok = isinstance(value, (float, int)) and not isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool) and INT32_MIN <= value <= INT32_MAX
    else:
        ok = isinstance(value, kind)
    return None if ok else f"{value!r} is not a valid {v.type} value"


@dataclass
class VariableTable:
    """The variables of one FMU, looked up by value reference or by name."""

    variables: tuple[Variable, ...]
    by_vr: dict[tuple[str, int], Variable] = field(init=False)
    by_name: dict[str, Variable] = field(init=False)
    by_type: dict[str, dict[int, Variable]] = field(init=False)
    cache: dict = field(init=False, default_factory=dict)   # derived lookups (access.py)
    independent: str | None = field(init=False, default=None)   # FMI 3.0: "time"
    # FMI 3.0 derivative inputs: (name, the input it differentiates, order)
    input_derivatives: tuple = field(init=False, default=())

    def __post_init__(self):
        self.variables = tuple(self.variables)
        self.by_vr = {}
        self.by_name = {}
        self.by_type = {t: {} for t in TYPES + FMI3_EMPTY}
        for v in self.variables:
            if v.name in self.by_name:
                raise VariableError(f'variable "{v.name}" is declared twice')
            if (v.type, v.value_reference) in self.by_vr:
                other = self.by_vr[(v.type, v.value_reference)].name
                raise VariableError(f'"{v.name}" and "{other}" share {v.type} value reference '
                                    f'{v.value_reference}')
            self.by_vr[(v.type, v.value_reference)] = v
            self.by_type[v.type][v.value_reference] = v
            self.by_name[v.name] = v
        for alias, internal in FMI3_TYPES.items():
            self.by_type[alias] = self.by_type[internal]
        for v in self.variables:
            for name in (v.dependencies or ()) + (v.initial_dependencies or ()) + \
                    ((v.derivative,) if v.derivative else ()):
                if name not in self.by_name:
                    raise VariableError(f'variable "{v.name}": "{name}" is not a variable')
        independents = [v.name for v in self.variables if v.causality == "independent"]
        if len(independents) > 1:
            raise VariableError(f"more than one independent variable: {independents}")
        self.independent = independents[0] if independents else None
        self.input_derivatives = tuple(self._input_derivatives())

    def _input_derivatives(self):
        for v in self.variables:
            if v.causality == "input" and v.derivative is not None:
                base, order = v.derivative, 1
                while self.by_name[base].derivative is not None:
                    base, order = self.by_name[base].derivative, order + 1
                yield v.name, base, order

    def start_values(self) -> dict[str, object]:
        """Name -> value at instantiation: the start value, or 0 / False / "" without one."""
        zero = {"Real": 0.0, "Integer": 0, "Boolean": False, "String": ""}
        return {v.name: (float(v.start) if v.type == "Real" and v.start is not None
                         else v.start if v.start is not None else zero[v.type])
                for v in self.variables}

    def lookup(self, type_name: str, vr: int) -> tuple[Variable | None, str | None]:
        """The variable of FMI type ``type_name`` with reference ``vr``, or (None, reason)."""
        internal = FMI3_TYPES.get(type_name, type_name)
        v = self.by_vr.get((internal, vr))
        if v is not None:
            return v, None
        others = [w.name for t in TYPES if t != internal
                  for w in [self.by_vr.get((t, vr))] if w is not None]
        if others:
            return None, f"value reference {vr} is {', '.join(others)}, not a {type_name} variable"
        return None, f"unknown {type_name} value reference {vr}"
