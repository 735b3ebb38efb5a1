"""FMI 3.0 on the same slave as FMI 2.0: the two protocol methods whose FMI 3.0 functions
differ from FMI 2.0's, the input derivatives of FMI 3.0 FMUs, and the names messages use.

* ``fmi3_enter_initialization_mode`` is FMI 2.0's fmi2SetupExperiment and
  fmi2EnterInitializationMode in one call;
* ``fmi3_do_step`` is fmi2DoStep returning ``(terminateSimulation, lastSuccessfulTime)``;
* FMI 3.0 has no fmi2SetRealInputDerivatives (its replacement, Intermediate Update Mode,
  is not provided): an input ``u`` the model can follow as a polynomial comes with
  derivative inputs ``der(u)`` and ``der(u,2)`` (FMI 3.0 variables whose ``derivative``
  attribute names ``u``, resp. ``der(u)``). Before each step their values go to the
  model's ``set_input_derivatives`` when any is non-zero or was set since the last step,
  so over [t, t + h] the input is ``u + der(u) tau + der(u,2) tau^2 / 2``; a master that
  never sets them gets the zero-order hold, as from an FMI 2.0 master that gives no input
  derivatives;
* messages name FMI 3.0's functions and states (``fmi3_text``).
"""

from __future__ import annotations

import re

from . import status

# FMI 2.0 function name (after "fmi2") -> its FMI 3.0 counterpart (after "fmi3"); others
# keep their name.
RENAMED = {"GetReal": "GetFloat64", "SetReal": "SetFloat64", "GetInteger": "GetInt32",
           "SetInteger": "SetInt32", "SetupExperiment": "EnterInitializationMode",
           "GetFMUstate": "GetFMUState", "SetFMUstate": "SetFMUState",
           "FreeFMUstate": "FreeFMUState", "SerializedFMUstateSize": "SerializedFMUStateSize",
           "SerializeFMUstate": "SerializeFMUState", "DeSerializeFMUstate": "DeserializeFMUState",
           "GetRealOutputDerivatives": "GetOutputDerivatives",
           "Instantiate": "InstantiateCoSimulation"}
STATES = {"Step Complete": "Step Mode", "Step Failed": "Step Discarded"}
_NAME = re.compile(r"\bfmi2([A-Z][A-Za-z0-9]*)")
_STATE = re.compile("|".join(STATES))


def fmi3_text(text: str) -> str:
    """``text`` with FMI 2.0 function, status and state names in FMI 3.0's."""
    text = _NAME.sub(lambda m: "fmi3" + RENAMED.get(m.group(1), m.group(1)), text)
    return _STATE.sub(lambda m: STATES[m.group(0)], text)


class Fmi3Protocol:
    """Mixin of ``Slave``: the FMI 3.0 protocol methods (see the module docstring)."""

    def fmi3_enter_initialization_mode(self, tolerance_defined, tolerance, start, stop_defined,
                                       stop):
        code, _ = self.fmi2_setup_experiment(tolerance_defined, tolerance, start, stop_defined,
                                             stop)
        if code != status.OK:
            return code, None
        return self.fmi2_enter_initialization_mode()

    def fmi3_do_step(self, time: float, step_size: float, no_set_prior: bool):
        code, _ = self.fmi2_do_step(time, step_size, no_set_prior)
        if self._fmi_terminate or any(self.values[name] != 0.0
                                      for name, _, _ in self.variables.input_derivatives):
            # the wrapper's own steps return terminateSimulation false and push no
            # derivative inputs: such steps are Python's
            self.disarm_fast_steps()
        return code, (bool(self._fmi_terminate), float(self._fmi_time))

    @property
    def fast_time(self) -> int:
        """The independent variable's value reference, or -1 (FMI 2.0): the wrapper sets
        its value to t + h after each step it takes by itself, as ``_fmi_at`` does."""
        name = self.variables.independent
        return self.variables.by_name[name].value_reference if name else -1

    def _fmi_push_input_derivatives(self) -> None:
        """Derivative inputs (FMI 3.0) to the model, before a step (module docstring)."""
        names, orders, values = [], [], []
        for name, base, order in self.variables.input_derivatives:
            value = self.values[name]
            if value != 0.0 or name in self.set_since_step:
                names.append(base)
                orders.append(order)
                values.append(value)
        if names:
            self.set_input_derivatives(names, orders, values)
