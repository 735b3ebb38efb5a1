"""One mass of the linear two-mass oscillator: a companion FMU of the two_mass_oscillator
scenario (the standard coupling benchmark of Schweizer and Lu, and of Gomes et al.).

A mass ``m`` on a wall spring ``c`` and damper ``d``, with an external force input and,
when ``cc`` or ``dc`` is not zero, the coupling spring and damper to the other mass, whose
position and velocity are inputs:

    m x'' = -c x - d x' + force + cc (x_other - x) + dc (v_other - x')

Outputs: ``x``, ``v`` and ``coupling_force = cc (x - x_other) + dc (v - v_other)``, the
force the coupling element exerts on the other mass (direct feedthrough of the inputs).
Force-displacement coupling: one instance holds the coupling element and sends its force
to the other; displacement-displacement: both hold it (each its own copy) and exchange
positions and velocities.

Over a step the inputs hold, or follow the polynomials of the derivatives the master gives
(``canInterpolateInputs``); the step is exact for polynomial inputs: the state and the
inputs' Taylor coefficients form one linear system ``z' = F z`` whose solution is
``expm(F h) z`` (scaling and squaring of the Taylor series, to rounding). The FMU adds no
integration error, only the coupling's. Output derivatives are exact too.
"""

import math

from mbdfmu.fmu_build.runtime import companion as base

INPUTS = ("force", "x_other", "v_other")
ORDER = 3          # input polynomials up to degree ORDER - 1


def expm(a):
    """exp(a) of a small square matrix (lists): scaling, 20 Taylor terms, squaring."""
    n = len(a)
    norm = max(sum(abs(x) for x in row) for row in a)
    s = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0 else 0
    a = [[x / 2 ** s for x in row] for row in a]
    result = [[float(i == j) for j in range(n)] for i in range(n)]
    term = [row[:] for row in result]
    for k in range(1, 21):
        term = [[sum(term[i][m] * a[m][j] for m in range(n)) / k for j in range(n)]
                for i in range(n)]
        result = [[result[i][j] + term[i][j] for j in range(n)] for i in range(n)]
    for _ in range(s):
        result = [[sum(result[i][m] * result[m][j] for m in range(n)) for j in range(n)]
                  for i in range(n)]
    return result


class Oscillator(base.CompanionSlave):
    # OSP power ports (ECCO): the external force on this mass and its velocity; the
    # coupling force it exerts on the other mass and that mass's velocity
    POWER_PORTS = {"mass": ("force", "v"), "coupling": ("coupling_force", "v_other")}
    DESCRIPTION = "Mass on a wall spring and damper, with an optional coupling spring to another mass"
    INTERPOLATES_INPUTS = True
    VARIABLES = (
        base.Var("m", "parameter", "kg", 1.0, "mass"),
        base.Var("c", "parameter", "N/m", 100.0, "wall spring stiffness"),
        base.Var("d", "parameter", "N.s/m", 0.1, "wall damper"),
        base.Var("cc", "parameter", "N/m", 0.0, "coupling spring stiffness (0: none here)"),
        base.Var("dc", "parameter", "N.s/m", 0.0, "coupling damper (0: none here)"),
        base.Var("x0", "parameter", "m", 0.0, "position at the start"),
        base.Var("v0", "parameter", "m/s", 0.0, "velocity at the start"),
        base.Var("force", "input", "N", 0.0, "external force on the mass"),
        base.Var("x_other", "input", "m", 0.0, "position of the other mass"),
        base.Var("v_other", "input", "m/s", 0.0, "velocity of the other mass"),
        base.Var("x", "output", "m", 0.0, "position"),
        base.Var("v", "output", "m/s", 0.0, "velocity"),
        base.Var("coupling_force", "output", "N", 0.0,
                 "force of the coupling element on the other mass"),
    )

    def initial_state(self):
        if not self.values["m"] > 0:
            raise ValueError(f"m must be positive, got {self.values['m']}")
        return {"x": self.values["x0"], "v": self.values["v0"]}

    def acceleration(self, x, v, force, xo, vo):
        p = self.values
        return (-p["c"] * x - p["d"] * v + force + p["cc"] * (xo - x) + p["dc"] * (vo - v)) / p["m"]

    def step(self, t, h, state):
        # z = [x, v, u_0, u_1, u_2 for each input]: u_k the k-th derivative at t
        n = 2 + ORDER * len(INPUTS)
        f = [[0.0] * n for _ in range(n)]
        f[0][1] = 1.0
        p = self.values
        f[1][0], f[1][1] = -(p["c"] + p["cc"]) / p["m"], -(p["d"] + p["dc"]) / p["m"]
        z = [state["x"], state["v"]]
        for j, (name, gain) in enumerate(zip(INPUTS, (1.0, p["cc"], p["dc"]))):
            first = 2 + ORDER * j
            f[1][first] = gain / p["m"]
            for k in range(ORDER - 1):
                f[first + k][first + k + 1] = 1.0
            taylor = self.input_taylor(name, t)[:ORDER]
            z += taylor + [0.0] * (ORDER - len(taylor))
        e = expm([[x * h for x in row] for row in f])
        x, v = (sum(e[i][k] * z[k] for k in range(n)) for i in (0, 1))
        return {"x": x, "v": v}

    def rates(self, state):
        """The equation of motion at the communication point (directional derivatives)."""
        a = self.acceleration(state["x"], state["v"], self.input("force"),
                              self.input("x_other"), self.input("v_other"))
        return {"x": state["v"], "v": a}

    def outputs(self, state):
        p = self.values
        xo, vo = self.input("x_other"), self.input("v_other")
        return {"x": state["x"], "v": state["v"],
                "coupling_force": p["cc"] * (state["x"] - xo) + p["dc"] * (state["v"] - vo)}

    def output_derivatives(self, state):
        """Exact: x' = v, x'' = v' = a; v'' = a' from the state and the inputs' rates."""
        p, t = self.values, self.time
        x, v = state["x"], state["v"]
        u = {n: (self.input_taylor(n, t) + [0.0, 0.0])[:3] for n in INPUTS}
        a = self.acceleration(x, v, u["force"][0], u["x_other"][0], u["v_other"][0])
        # the equation is linear: differentiating it in time gives the jerk
        jerk = self.acceleration(v, a, u["force"][1], u["x_other"][1], u["v_other"][1])
        cf = (p["cc"] * (v - u["x_other"][1]) + p["dc"] * (a - u["v_other"][1]),
              p["cc"] * (a - u["x_other"][2]) + p["dc"] * (jerk - u["v_other"][2]))
        return {"x": (v, a), "v": (a, jerk), "coupling_force": cf}
