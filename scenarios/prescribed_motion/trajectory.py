"""Trajectory generator: a companion FMU of the prescribed_motion scenario (no inputs).

    position = start + rate t + amplitude sin(2 pi frequency t)

with its exact velocity and acceleration as outputs, at the FMU's time. With
``amplitude = 0`` it is P4's constant crank rate.
"""

import math

from mbdfmu.fmu_build.runtime import companion as base


def motion(t, start, rate, amplitude, frequency):
    """(position, velocity, acceleration) at time t."""
    w = 2 * math.pi * frequency
    return (start + rate * t + amplitude * math.sin(w * t),
            rate + amplitude * w * math.cos(w * t),
            -amplitude * w * w * math.sin(w * t))


class Trajectory(base.CompanionSlave):
    DESCRIPTION = "Joint trajectory: a constant rate plus a harmonic, with its derivatives"
    VARIABLES = (
        base.Var("start", "parameter", "rad", 0.0, "position at t = 0"),
        base.Var("rate", "parameter", "rad/s", 314.1592653589793, "constant rate"),
        base.Var("amplitude", "parameter", "rad", 0.0, "amplitude of the harmonic"),
        base.Var("frequency", "parameter", "Hz", 0.0, "frequency of the harmonic"),
        base.Var("position", "output", "rad", 0.0, "position"),
        base.Var("velocity", "output", "rad/s", 0.0, "velocity"),
        base.Var("acceleration", "output", "rad/s2", 0.0, "acceleration"),
    )

    def outputs(self, state):
        p = self.values
        pos, vel, acc = motion(self.time, p["start"], p["rate"], p["amplitude"], p["frequency"])
        return {"position": pos, "velocity": vel, "acceleration": acc}
