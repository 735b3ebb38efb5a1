"""Valve command: a companion FMU of the hydraulic_crane scenario (no inputs).

A trapezoid: 0 until ``t_open``, a linear ramp to ``opening`` over ``ramp`` seconds, held
until ``t_close``, a ramp back to 0. The output is the profile at the FMU's time.
"""

from mbdfmu.fmu_build.runtime import companion as base


def trapezoid(t, t_open, t_close, ramp, opening):
    """The command at time t."""
    if t <= t_open or t >= t_close + ramp:
        return 0.0
    if t < t_open + ramp:
        return opening * (t - t_open) / ramp
    if t <= t_close:
        return opening
    return opening * (t_close + ramp - t) / ramp


class ValveCommand(base.CompanionSlave):
    DESCRIPTION = "Trapezoidal valve command: open, hold, close"
    VARIABLES = (
        base.Var("t_open", "parameter", "s", 0.2, "start of the opening ramp"),
        base.Var("t_close", "parameter", "s", 1.2, "start of the closing ramp"),
        base.Var("ramp", "parameter", "s", 0.1, "duration of each ramp"),
        base.Var("opening", "parameter", "1", 0.5, "spool position while open"),
        base.Var("u", "output", "1", 0.0, "valve command"),
    )

    def outputs(self, state):
        p = self.values
        return {"u": trapezoid(self.time, p["t_open"], p["t_close"], p["ramp"], p["opening"])}
