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
        self.address = (self.values.ctypes.data, self.mask.ctypes.data,
                        self.valid.ctypes.data, count)

    def publish(self, values: dict) -> None:
        """Refresh from ``values`` and let the wrapper serve them (all must be numbers)."""
        try:
            self.values[self.vrs] = self.read(values)
        except (KeyError, TypeError, ValueError):
            return
        self.valid[0] = 1

    def invalidate(self) -> None:
        self.valid[0] = 0
