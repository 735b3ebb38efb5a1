"""The Real values the C wrapper serves by itself: fmi2GetReal after a step, without
entering Python.

``RealCache`` holds every Real variable's value by value reference in an array the
wrapper reads (``fast_real``: the addresses of the values, of a mask of the Real value
references, and of a validity flag, and their count). The wrapper clears the flag before
every call into the runtime except fmi2Get*, so a value set, a state restored, a reset or
anything else makes it read through Python again; the slave sets the flag only after a
successful fmi2DoStep in Step Complete, with the cache refreshed from ``values``. A get
that names anything but Real variables of this FMU also goes through Python (which
checks it and says what is wrong).
"""

from __future__ import annotations

from operator import itemgetter

import numpy as np

from . import status


class RealCache:
    """The Real variables of a ``VariableTable``, as the wrapper reads them."""

    def __init__(self, table):
        reals = table.by_type["Real"]
        count = max(reals, default=-1) + 1
        self.vrs = np.array(sorted(reals), dtype=np.intp)
        names = [reals[vr].name for vr in self.vrs.tolist()]
        self.read = itemgetter(*names) if len(names) > 1 else (lambda values: (values[names[0]],)
                                                                if names else ())
        self.values = np.zeros(max(count, 1))
        self.mask = np.zeros(max(count, 1), dtype=np.uint8)
        self.mask[self.vrs] = 1
        self.valid = np.zeros(1, dtype=np.int64)
        # the values the wrapper may still serve after it took fmi2SetReal of an input
        # itself (``keep_after_set``); none until the model says which
        self.kept = np.zeros(max(count, 1), dtype=np.uint8)
        self.address = (self.values.ctypes.data, self.mask.ctypes.data,
                        self.valid.ctypes.data, count, self.kept.ctypes.data)

    def publish(self, values: dict) -> None:
        """Refresh from ``values`` and let the wrapper serve them (all must be numbers)."""
        try:
            self.values[self.vrs] = self.read(values)
        except (KeyError, TypeError, ValueError):
            return
        self.valid[0] = 1

    def invalidate(self) -> None:
        self.valid[0] = 0

    def keep_after_set(self, vrs) -> None:
        """The value references whose values an input taken by the wrapper's set function
        (``FastSteps``) leaves as they are: a get of only these is served until the next
        step; any other get goes through Python."""
        self.kept[:] = 0
        self.kept[np.asarray(vrs, dtype=np.intp)] = 1


class FastSteps:
    """The communication steps the wrapper takes by itself: a control block of six
    integers the wrapper reads at every fmi2DoStep while the Real values are valid
    (``RealCache``): enabled, the address of a step function ``int f(model, context, t,
    h, values)`` (0: it took the step and refreshed ``values``, else Python must), its
    two context addresses, the count of steps it took (the wrapper adds to it), and 0 or
    the address of ``int set(context, vrs, nvr, new, values)`` that takes fmi2SetReal of
    inputs the step function reads (0: all applied; a get then goes through Python unless
    it names only values ``RealCache.keep_after_set`` keeps). The
    model arms it after a step when the next steps need no Python; the wrapper then asks
    the slave to catch up (``fmi_sync``) before any other call."""

    def __init__(self):
        self.block = np.zeros(6, dtype=np.int64)
        self.address = self.block.ctypes.data

    def arm(self, function: int, model: int, context: int, setter: int = 0) -> None:
        self.block[1:4] = (function, model, context)
        self.block[5] = setter
        self.block[0] = 1

    def taken(self) -> int:
        """Steps the wrapper took since the last call (the count starts again)."""
        count, self.block[4] = int(self.block[4]), 0
        return count

    def disarm(self) -> None:
        self.block[0] = 0


class FastStepProtocol:
    """Mixin of ``Slave``: arming ``FastSteps`` (its ``_fmi_fast_steps``) and catching up
    with the steps the wrapper took (``fmi_sync``, called by the wrapper)."""

    def arm_fast_steps(self, function: int, model: int, context: int, setter: int = 0) -> None:
        """Let the wrapper take the coming fmi2DoSteps by itself (``FastSteps``) until any
        other call; ``catch_up`` then brings the model to the time they reached. With
        ``setter``, fmi2SetReal too (``FastSteps``)."""
        self._fmi_fast_steps.arm(function, model, context, setter)

    def keep_after_set(self, vrs) -> None:
        """``RealCache.keep_after_set`` of this slave's Real values."""
        self._fmi_reals.keep_after_set(vrs)

    def set_fast_steps(self, armed: tuple | None) -> None:
        """``arm_fast_steps(*armed)``, or disarm them when ``armed`` is None."""
        if armed is None:
            self.disarm_fast_steps()
        else:
            self.arm_fast_steps(*armed)

    def disarm_fast_steps(self) -> None:
        self._fmi_fast_steps.disarm()

    def catch_up(self) -> float | None:
        """After steps the wrapper took by itself: the model's state at their end and
        its time, or None when there were none (models that arm ``FastSteps``)."""
        return None

    def set_in_wrapper(self, held, pending) -> None:
        """For ``catch_up``, of the Real variables the wrapper's set function takes,
        [(value reference, value)]: ``held`` the values the model now holds, ``pending``
        those it took after its last step, now set as fmi2SetReal sets them (the next step
        and every get then go through Python)."""
        reals = self.variables.by_type["Real"]
        self.values.update((reals[vr].name, value) for vr, value in held)
        if not pending:
            return
        for vr, value in pending:
            self.values[reals[vr].name] = self.set_since_step[reals[vr].name] = value
        self._fmi_stale = self._fmi_calculates
        self.disarm_fast_steps()
        self._fmi_reals.invalidate()

    def fmi_sync(self):
        """Called by the wrapper before any call that follows steps it took by itself."""
        taken = self._fmi_fast_steps.taken()
        try:
            t = self.catch_up()
        except BaseException as exc:  # noqa: B902 - nothing may reach the C side
            return self._fmi_error(f"fmi2DoStep (taken by the wrapper): {type(exc).__name__}: "
                                   f"{exc}"), None
        if t is not None:
            self._fmi_at(t)
            self.log(f"t = {t!r} s: {taken} communication steps taken by the wrapper without "
                     "Python (steps of the C kernel)")
        return status.OK, None
