"""Derivatives through the FMI 2.0 API (directional derivatives, input and output
derivatives) for ``Slave``: a mixin whose hooks a model overrides when it provides them
(and says so in the FMU's capabilities); by default each call is fmi2Error."""

from __future__ import annotations

from . import status
from .machine import fmi_function
from .status import FmiError


class DerivativeProtocol:
    """The derivative hooks a model may override and the protocol methods that call them."""

    def directional_derivative(self, unknowns, knowns, seeds):
        """d(unknowns)/d(knowns) times ``seeds`` (names, names, floats) -> floats."""
        raise FmiError("directional derivatives are not provided by this FMU")

    def set_input_derivatives(self, names, orders, values) -> None:
        """Derivatives of Real inputs (canInterpolateInputs)."""
        raise FmiError("input derivatives are not provided (canInterpolateInputs=false)")

    def output_derivatives(self, names, orders):
        """Derivatives of Real outputs (maxOutputDerivativeOrder > 0) -> floats."""
        raise FmiError("output derivatives are not provided (maxOutputDerivativeOrder=0)")

    @fmi_function("fmi2GetDirectionalDerivative")
    def fmi2_get_directional_derivative(self, unknown_vrs, known_vrs, seeds):
        unknowns, knowns = self._fmi_real_names(unknown_vrs), self._fmi_real_names(known_vrs)
        result = tuple(float(x) for x in self.directional_derivative(unknowns, knowns, list(seeds)))
        if len(result) != len(unknowns):
            raise FmiError(f"the model returned {len(result)} values for {len(unknowns)} unknowns")
        return status.OK, result

    @fmi_function("fmi2SetRealInputDerivatives")
    def fmi2_set_real_input_derivatives(self, vrs, orders, values):
        self.set_input_derivatives(self._fmi_real_names(vrs), list(orders), list(values))
        return status.OK, None

    @fmi_function("fmi2GetRealOutputDerivatives")
    def fmi2_get_real_output_derivatives(self, vrs, orders):
        result = tuple(float(x) for x in self.output_derivatives(self._fmi_real_names(vrs), list(orders)))
        if len(result) != len(vrs):
            raise FmiError(f"the model returned {len(result)} values for {len(vrs)} outputs")
        return status.OK, result

    def _fmi_real_names(self, vrs) -> list[str]:
        names = []
        for vr in vrs:
            v, reason = self.variables.lookup("Real", vr)
            if v is None:
                raise FmiError(reason)
            names.append(v.name)
        return names
