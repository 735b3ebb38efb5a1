"""Cart-pendulum controller: a companion FMU of the cart_pendulum_pid scenario.

A PID on the cart position plus state feedback (PD) on the pole angle:

    e = x - x_ref(t),   force = kp_x e + ki_x z + kd_x v + kp_phi (phi - phi_ref) + kd_phi omega,
    z' = e

clipped to ``[-force_max, force_max]``; ``x_ref`` steps from ``x_ref0`` to ``x_ref1`` at
``t_step``. The gains of connections.toml are an LQR design on the linearized cart-pole
(see README.md). The integral ``z`` is exact for inputs held over a step (zero-order hold),
with the set point evaluated at the step's start. The force reads the inputs: direct
feedthrough (a Jacobi master delays it by one step; Gauss-Seidel with the mechanism first
does not).
"""

from mbdfmu.fmu_build.runtime import companion as base


class PIDController(base.CompanionSlave):
    STATE_INFO = {"z": ("m.s", "integral of the cart's position error x - x_ref")}
    POWER_PORTS = {"cart": ("force", "v")}     # OSP power port (ECCO)
    DESCRIPTION = "PID on the cart position with PD feedback of the pole angle: force out"
    VARIABLES = (
        base.Var("kp_x", "parameter", "N/m", 16.956, "proportional gain, cart position"),
        base.Var("ki_x", "parameter", "N/(m.s)", 7.071, "integral gain, cart position"),
        base.Var("kd_x", "parameter", "N.s/m", 13.260, "derivative gain (cart velocity)"),
        base.Var("kp_phi", "parameter", "N/rad", -65.198, "proportional gain, pole angle"),
        base.Var("kd_phi", "parameter", "N.s/rad", -13.093, "derivative gain (pole rate)"),
        base.Var("phi_ref", "parameter", "rad", 1.5707963267948966, "upright pole angle"),
        base.Var("x_ref0", "parameter", "m", 0.0, "cart set point before t_step"),
        base.Var("x_ref1", "parameter", "m", 1.0, "cart set point from t_step"),
        base.Var("t_step", "parameter", "s", 1.0, "time of the set-point step"),
        base.Var("force_max", "parameter", "N", 100.0, "force limit"),
        base.Var("x", "input", "m", 0.0, "cart position"),
        base.Var("v", "input", "m/s", 0.0, "cart velocity"),
        base.Var("phi", "input", "rad", 1.5707963267948966, "pole angle"),
        base.Var("omega", "input", "rad/s", 0.0, "pole rate"),
        base.Var("force", "output", "N", 0.0, "force on the cart, +x"),
        base.Var("x_ref", "output", "m", 0.0, "cart set point"),
    )

    def set_point(self, t):
        p = self.values
        return p["x_ref1"] if t >= p["t_step"] else p["x_ref0"]

    def initial_state(self):
        return {"z": 0.0}

    def step(self, t, h, state):
        return {"z": state["z"] + (self.values["x"] - self.set_point(t)) * h}

    def rates(self, state):
        """z' = x - x_ref at the communication point (directional derivatives)."""
        return {"z": self.values["x"] - self.set_point(self.time)}

    def outputs(self, state):
        p = self.values
        x_ref = self.set_point(self.time)
        force = (p["kp_x"] * (p["x"] - x_ref) + p["ki_x"] * state["z"] + p["kd_x"] * p["v"]
                 + p["kp_phi"] * (p["phi"] - p["phi_ref"]) + p["kd_phi"] * p["omega"])
        force = max(-p["force_max"], min(p["force_max"], force))
        return {"force": force, "x_ref": x_ref}
