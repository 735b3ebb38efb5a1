"""Hydraulic cylinder with a proportional 4/3 valve: a companion FMU of the hydraulic_crane
scenario (force-displacement coupling: length and rate in, force out).

Chambers A (cap side, area A_A) and B (rod side, A_B) of a double-acting cylinder whose
length is ``s`` (``x = s - s_min`` the piston travel, ``stroke`` its range):

    V_A = V_A0 + A_A x,            V_B = V_B0 + A_B (stroke - x)
    p_A' = beta / V_A (Q_A - A_A s' - Q_leak),   p_B' = beta / V_B (Q_B + A_B s' + Q_leak)
    force = p_A A_A - p_B A_B - b s'      (positive pushes the cylinder's ends apart)

The valve spool ``u`` in [-1, 1] (input ``valve``) connects A to supply and B to tank when
positive, the reverse when negative, through orifices ``Q = Q_nom |u| f(dp) / sqrt(dp_nom)`` with the
regularized square root ``f(dp) = dp / (dp^2 + dp_t^2)^(1/4)`` (``sqrt(dp)`` for
``dp >> dp_t``, linear near 0, so the equations stay smooth). ``Q_leak = C_leak (p_A - p_B)``.

The start pressures hold the given start force: ``p_B(0) = pB0``,
``p_A(0) = (force0 + pB0 A_B) / A_A``.

Over a communication step the inputs hold, and the length follows its rate:
``s(t + tau) = s + s' tau``; with input derivatives from the master
(``canInterpolateInputs``) the length and the rate follow their own polynomials. The pressures are integrated by classical Runge-Kutta in
substeps of at most ``max_substep``. The force reads the rate input: direct feedthrough.
"""


from mbdfmu.fmu_build.runtime import companion as base


def orifice(dp, dp_t):
    """Regularized square root: dp / (dp^2 + dp_t^2)^(1/4)."""
    return dp / (dp * dp + dp_t * dp_t) ** 0.25


class HydraulicCylinder(base.CompanionSlave):
    # the rod's force and the rate it acts on (OSP power port, ECCO)
    POWER_PORTS = {"rod": ("force", "rate")}
    DESCRIPTION = ("Double-acting hydraulic cylinder with a proportional valve: "
                   "length, rate and valve in, force out")
    INTERPOLATES_INPUTS = True
    VARIABLES = (
        base.Var("A_A", "parameter", "m2", 1.9635e-3, "piston area, cap side (50 mm bore)"),
        base.Var("A_B", "parameter", "m2", 1.3477e-3, "annulus area, rod side (28 mm rod)"),
        base.Var("s_min", "parameter", "m", 0.6, "cylinder length with the piston at x = 0"),
        base.Var("stroke", "parameter", "m", 0.6, "piston travel"),
        base.Var("V_A0", "parameter", "m3", 2.0e-4, "dead volume of chamber A and its hose"),
        base.Var("V_B0", "parameter", "m3", 2.0e-4, "dead volume of chamber B and its hose"),
        base.Var("beta", "parameter", "Pa", 1.0e9, "effective bulk modulus"),
        base.Var("p_supply", "parameter", "Pa", 16.0e6, "supply pressure"),
        base.Var("p_tank", "parameter", "Pa", 1.0e5, "tank pressure"),
        base.Var("Q_nom", "parameter", "m3/s", 3.333e-4,
                 "nominal flow of a valve edge, full opening (20 l/min)"),
        base.Var("dp_nom", "parameter", "Pa", 3.5e6, "pressure drop of the nominal flow"),
        base.Var("dp_t", "parameter", "Pa", 1.0e5, "pressure drop below which the orifice is linear"),
        base.Var("C_leak", "parameter", "m3/(s.Pa)", 1.0e-14, "internal leakage A to B"),
        base.Var("b", "parameter", "N.s/m", 2.0e3, "viscous friction of the piston"),
        base.Var("force0", "parameter", "N", 0.0, "force at the start (sets p_A(0))"),
        base.Var("pB0", "parameter", "Pa", 2.0e6, "pressure in B at the start"),
        base.Var("max_substep", "parameter", "s", 1.0e-4, "longest Runge-Kutta substep"),
        base.Var("length", "input", "m", 0.85, "cylinder length s"),
        base.Var("rate", "input", "m/s", 0.0, "cylinder length rate s'"),
        base.Var("valve", "input", "1", 0.0, "valve spool, -1 (retract) .. 1 (extend)"),
        base.Var("force", "output", "N", 0.0, "force pushing the cylinder's ends apart"),
        base.Var("p_A", "output", "Pa", 0.0, "pressure in chamber A"),
        base.Var("p_B", "output", "Pa", 0.0, "pressure in chamber B"),
    )

    def initial_state(self):
        p = self.values
        return {"p_A": (p["force0"] + p["pB0"] * p["A_B"]) / p["A_A"], "p_B": p["pB0"]}

    def flows(self, pA, pB, valve):
        """(Q_A, Q_B) into the chambers through the valve (spool ``valve``) and the leak."""
        p = self.values
        u = max(-1.0, min(1.0, valve))
        ps, pt, dpt = p["p_supply"], p["p_tank"], p["dp_t"]
        k = p["Q_nom"] / p["dp_nom"] ** 0.5
        if u >= 0:
            qa, qb = k * u * orifice(ps - pA, dpt), -k * u * orifice(pB - pt, dpt)
        else:
            qa, qb = -k * -u * orifice(pA - pt, dpt), k * -u * orifice(ps - pB, dpt)
        leak = p["C_leak"] * (pA - pB)
        return qa - leak, qb + leak

    def pressure_rates(self, pA, pB, length, rate, valve):
        """(p_A', p_B') at the pressures, the cylinder's length and rate and the spool."""
        p = self.values
        x = length - p["s_min"]
        VA = p["V_A0"] + p["A_A"] * x
        VB = p["V_B0"] + p["A_B"] * (p["stroke"] - x)
        if VA <= 0 or VB <= 0:
            raise base.Discard(f"the piston left its stroke: x = {x:.4g} m")
        qa, qb = self.flows(pA, pB, valve)
        return [p["beta"] / VA * (qa - p["A_A"] * rate), p["beta"] / VB * (qb + p["A_B"] * rate)]

    def rates(self, state):
        """The pressures' rates at the communication point (directional derivatives)."""
        a, b = self.pressure_rates(state["p_A"], state["p_B"], self.input("length"),
                                   self.input("rate"), self.input("valve"))
        return {"p_A": a, "p_B": b}

    def step(self, t, h, state):
        p = self.values
        length, rate0 = self.input_taylor("length", t), self.input_taylor("rate", t)
        held = len(length) == 1 and len(rate0) == 1   # zero-order hold: s follows the rate

        def rhs(tau, y):
            if held:
                s, rate = length[0] + rate0[0] * (tau - t), rate0[0]
            else:
                s, rate = self.input("length", tau), self.input("rate", tau)
            return self.pressure_rates(y[0], y[1], s, rate, self.input("valve", tau))

        pA, pB = base.rk4(rhs, t, [state["p_A"], state["p_B"]], h,
                          p["max_substep"])
        return {"p_A": pA, "p_B": pB}

    def outputs(self, state):
        p = self.values
        return {"force": state["p_A"] * p["A_A"] - state["p_B"] * p["A_B"]
                - p["b"] * self.input("rate"),
                "p_A": state["p_A"], "p_B": state["p_B"]}
