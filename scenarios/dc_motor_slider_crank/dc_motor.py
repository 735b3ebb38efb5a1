"""DC motor (armature circuit only): a companion FMU of the dc_motor_slider_crank scenario.

    L di/dt = V - R i - ke w,        torque = kt i

Inputs: the supply voltage V and the shaft speed w (from the mechanism). Output: the torque
on the shaft and the current. The rotor's inertia belongs to the mechanism (lumped into the
crank), so the torque is the electromagnetic torque; no direct feedthrough (the torque is
a function of the state i only).

Over a communication step the inputs hold (zero-order hold), or follow the polynomials of
the derivatives the master gives (``canInterpolateInputs``), and the current follows the
exact solution of the linear equation ``i' = -a i + b(tau)``, ``a = R / L``,
``b = (V - ke w) / L`` a polynomial in tau: ``i = p(tau) + (i(t) - p(0)) exp(-a tau)``
with the polynomial particular solution ``p`` (for inputs held,
``i(t + h) = i_inf + (i - i_inf) exp(-R h / L)``, ``i_inf = (V - ke w) / R``): the FMU adds
no integration error, only the coupling's.
"""

import math

from mbdfmu.fmu_build.runtime import companion as base


class DCMotor(base.CompanionSlave):
    POWER_PORTS = {"shaft": ("torque", "speed")}     # OSP power port (ECCO)
    DESCRIPTION = "DC motor armature: voltage and speed in, torque out (exact over each step)"
    INTERPOLATES_INPUTS = True
    VARIABLES = (
        base.Var("R", "parameter", "Ohm", 0.5, "armature resistance"),
        base.Var("L", "parameter", "H", 2.0e-3, "armature inductance"),
        base.Var("kt", "parameter", "N.m/A", 0.1, "torque constant"),
        base.Var("ke", "parameter", "V.s/rad", 0.1, "back-EMF constant"),
        base.Var("i0", "parameter", "A", 0.0, "current at the start time"),
        base.Var("voltage", "input", "V", 12.0, "supply voltage"),
        base.Var("speed", "input", "rad/s", 0.0, "shaft speed"),
        base.Var("torque", "output", "N.m", 0.0, "electromagnetic torque on the shaft, kt i"),
        base.Var("current", "output", "A", 0.0, "armature current"),
    )

    def initial_state(self):
        if not (self.values["R"] > 0 and self.values["L"] > 0):
            raise ValueError(f"R and L must be positive, got R = {self.values['R']}, "
                             f"L = {self.values['L']}")
        return {"current": self.values["i0"]}

    def step(self, t, h, state):
        p = self.values
        a = p["R"] / p["L"]
        volts, speed = self.input_taylor("voltage", t), self.input_taylor("speed", t)
        n = max(len(volts), len(speed))
        volts, speed = volts + [0.0] * (n - len(volts)), speed + [0.0] * (n - len(speed))
        # b(tau) = sum beta_k tau^k; the particular solution sum c_k tau^k
        beta = [(v - p["ke"] * w) / p["L"] / math.factorial(k)
                for k, (v, w) in enumerate(zip(volts, speed))]
        c = [0.0] * (n + 1)
        for k in reversed(range(n)):
            c[k] = (beta[k] - (k + 1) * c[k + 1]) / a
        particular = sum(ck * h ** k for k, ck in enumerate(c))
        return {"current": particular + (state["current"] - c[0]) * math.exp(-a * h)}

    def rates(self, state):
        """L di/dt = V - R i - ke w at the communication point (directional derivatives)."""
        p = self.values
        return {"current": (self.input("voltage") - p["R"] * state["current"]
                            - p["ke"] * self.input("speed")) / p["L"]}

    def outputs(self, state):
        return {"torque": self.values["kt"] * state["current"], "current": state["current"]}
