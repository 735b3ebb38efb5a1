"""A companion's continuous states as FMU variables, and its directional derivatives.

A companion class that defines ``rates(state)`` (the time derivative of each entry of its
state at ``self.time``, with the inputs as they are now: the equations ``step``
integrates) exposes its states and their derivatives, and provides directional
derivatives (docs/fmu.md, "Directional derivatives"):

* a state whose key is an output's name is that output (the oscillator's ``x``); any
  other is a local variable of that name (its unit and description from the class's
  ``STATE_INFO = {key: (unit, description)}``); its derivative is the local
  ``der(<key>)`` (FMI's ``derivative`` attribute names the state);
* ``directional(model, unknowns, knowns, seeds)``: the derivatives of outputs and state
  derivatives with respect to inputs and states at the communication point, by central
  differences of ``outputs`` and ``rates`` themselves along the seed direction (at
  ``eps`` and ``eps / 2``, Richardson's extrapolation; no step is integrated).
"""

from __future__ import annotations

from .status import FmiError

# Relative size of the finite-difference step along a direction.
DELTA = 1e-4


def derivative_name(state_variable: str) -> str:
    return f"der({state_variable})"


def _evaluate(model, state: dict, inputs: dict) -> dict:
    """Every output and ``der(...)`` at ``state`` with the inputs ``inputs`` (name ->
    value) replacing the current ones."""
    saved = {n: model.values[n] for n in inputs}
    model.values.update(inputs)
    try:
        out = model.companion.outputs(state)
        rates = model.companion.rates(state)
    finally:
        model.values.update(saved)
    values = {n: float(out[n]) for n in model.OUTPUTS}
    values.update({derivative_name(model.STATE_VARIABLES[k]): float(v) for k, v in rates.items()})
    return values


def directional(model, unknowns, knowns, seeds) -> list[float]:
    """``CompanionModel.directional_derivative`` (module docstring)."""
    by_variable = {v: k for k, v in model.STATE_VARIABLES.items()}
    inputs = {v.name for v in model.variables.variables
              if v.causality == "input" and v.derivative is None}
    for name in knowns:
        if name not in by_variable and name not in inputs:
            raise FmiError(f'"{name}" is not a known of the directional derivatives (the '
                           "inputs and the continuous states)")
    base = _evaluate(model, model.state, {})
    for name in unknowns:
        if name not in base and name not in by_variable:
            raise FmiError(f'"{name}" is not an unknown of the directional derivatives (the '
                           "outputs and the state derivatives)")
    direction = {n: 0.0 for n in knowns}
    for name, seed in zip(knowns, seeds):
        direction[name] += seed
    ratios = [max(1.0, abs(model.values[n] if n in inputs else model.state[by_variable[n]]))
              / abs(d) for n, d in direction.items() if d]
    if not ratios:
        return [0.0] * len(unknowns)
    eps = DELTA * min(ratios)      # no component moves by more than DELTA of its size

    def at(e):
        state = dict(model.state)
        moved = {}
        for name, d in direction.items():
            if name in by_variable:
                state[by_variable[name]] += e * d
            else:
                moved[name] = model.values[name] + e * d
        return _evaluate(model, state, moved)

    def central(e):
        plus, minus = at(e), at(-e)
        return {n: (plus[n] - minus[n]) / (2 * e) for n in plus}

    coarse, fine = central(eps), central(eps / 2)
    return [(4 * fine[n] - coarse[n]) / 3 if n in fine else direction.get(n, 0.0)
            for n in unknowns]
