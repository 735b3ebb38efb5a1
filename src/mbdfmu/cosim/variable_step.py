"""The fmpy master's error-controlled variable communication step, with rollback.

Each macro step (of either algorithm) is checked after the fact: for every connection the
input that was held over the step is compared with the output it stood for at the end of
the step (the zero-order hold's extrapolation against the actual value); scaled by
``atol + rtol * nominal``, the largest of these is the step's coupling error. Above 1, or
when an instance discards the step, every instance is rolled back with ``fmi2SetFMUstate``
to the state saved at t and the step is retried smaller (see ``fmpy_master.py``'s
docstring for jumps and the smallest step).
"""

from __future__ import annotations

import math

from .settings import CosimError, Refused

# Aim at this fraction of the allowed coupling error.
SAFETY = 0.8
# Largest growth of the step after an accepted step, smallest factor after a rejected one.
MAX_FACTOR = 2.0
MIN_FACTOR = 0.1
# A step this much longer than planned may end the run.
LAST_STEP_STRETCH = 1.1
# A retried (shorter) step whose error shrank less than the step ratio to this power has
# met a jump of an output (a set point, a switch), not a coupling error, which shrinks at
# least in proportion to the step.
JUMP_EXPONENT = 0.5
# Rejections in a row before the variable-step master gives up.
MAX_REJECTIONS_IN_A_ROW = 40


def run_variable_step(system, algorithm, scenario, settings, h, t_end, out) -> None:
    """Step ``system`` from 0 to ``t_end`` with error-controlled steps, recording into ``out``."""
    vs = scenario.variable_step
    rtol = settings.rtol or vs.rtol
    atol = settings.atol or vs.atol
    h_min = settings.h_min or vs.h_min
    h_max = settings.h_max or vs.h_max or 10 * h
    h = min(vs.h_initial or h, h_max)
    t, rejections, rejected_err, rejected_step = 0.0, 0, math.inf, math.inf
    # the error estimate is O(h^(p+1)) for inputs extrapolated at order p
    exponent = 1.0 / (system.extrapolation.order + 1)
    while t < t_end * (1 - 1e-12):
        # A step that would leave less than a tenth of itself before t_end is stretched to
        # t_end (no sliver of a last step).
        last = t + LAST_STEP_STRETCH * h >= t_end * (1 - 1e-12)
        t_next = t_end if last else t + h
        step = t_next - t  # the step is a difference of times: a replay of the times repeats it
        saved = system.get_states()
        try:
            try:
                algorithm.step(system, t, step, first=settings.start == "zero" and t == 0.0)
                err = system.coupling_error(rtol, atol, vs.nominal)
                reason = f"coupling error {err:.3g} > 1"
            except Refused as exc:
                err, reason = math.inf, str(exc)
            # An error that does not shrink with the step is a jump of an output (a set
            # point, a switch), not a coupling error: accept the step and go on.
            jump = (math.isfinite(err) and rejections > 0
                    and err >= (step / rejected_step) ** JUMP_EXPONENT * rejected_err)
            forced = math.isfinite(err) and step <= h_min * (1 + 1e-9)
            if not err <= 1.0 and not jump and not forced:
                rejected_err, rejected_step = err, step
                system.set_states(saved)
                system.counters["rejected"] += 1
                system.counters["rollbacks"] += 1
                rejections += 1
                factor = MIN_FACTOR if not math.isfinite(err) else \
                    max(MIN_FACTOR, (SAFETY / err) ** exponent)
                h = step * factor
                if h < h_min:
                    if step <= h_min * (1 + 1e-9) or rejections > MAX_REJECTIONS_IN_A_ROW:
                        raise CosimError(f"an instance refuses even the smallest step "
                                         f"{h_min:g} s (h_min); last: {reason}", t)
                    h = h_min  # the next try is accepted whatever its error (if finite)
                continue
        finally:
            system.free_states(saved)
        if jump or (forced and err > 1.0):
            system.counters["jumps" if jump else "forced"] += 1
            err = 1.0
        rejections, rejected_err, rejected_step = 0, math.inf, math.inf
        t = t_next
        system.counters["steps"] += 1
        system.update_nominal()
        out.times.append(t)
        out.rows.append(system.sample())
        out.steps.append(step)
        h = min(h_max, step * (MAX_FACTOR if err == 0
                               else min(MAX_FACTOR, (SAFETY / err) ** exponent)))
