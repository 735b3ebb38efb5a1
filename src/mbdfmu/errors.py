"""The project's errors: one small hierarchy, caught once at each boundary (CLI, FMU).

Readers of files (scenes, scenarios) collect every problem, each located by file and item,
with ``Problems`` and raise them together, the way FMPy's validation reports everything at
once.
"""

from __future__ import annotations

import difflib


class MbdfmuError(Exception):
    """Base of every error mbdfmu raises on purpose."""


class ReadError(MbdfmuError):
    """A file that cannot be read or holds mistakes; ``problems`` lists each one, located
    (``slider_crank.toml: joint "A": unknown body "rodd" (did you mean "rod"?)``)."""

    def __init__(self, problems: list[str] | str):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("; ".join(self.problems))


class SceneError(ReadError):
    """A scene file that cannot be read, or a scene that cannot be built."""


class AssemblyError(SceneError):
    """Initial positions or velocities that cannot be made to satisfy the constraints."""


class SettingError(MbdfmuError, ValueError):
    """A solver or run setting out of range; ``setting`` names it, ``where`` says where it
    was given (``--step``, ``pendulum.toml: simulation``, the FMU parameter ``solver.step``)."""

    def __init__(self, setting: str, message: str, where: str = ""):
        self.setting, self.where = setting, where
        super().__init__(f"{where}: {message}" if where else message)


class SolverError(MbdfmuError):
    """An integration that cannot go on: time and reason are in the message."""

    def __init__(self, message: str, t: float | None = None):
        self.t = t
        self.reason = message
        prefix = f"t = {t:.9g} s: " if t is not None else ""
        super().__init__(prefix + message)


class AccuracyError(SolverError):
    """A fixed-step run whose estimated error exceeds what its stated accuracy allows: a
    smaller step may succeed (auto retries with one, ``auto_watch.py``)."""


class WorkLimitError(SolverError):
    """The work allowed for one advance (internal steps, CPU time) ran out before its target
    time: a shorter advance may succeed, unlike the other solver failures."""


class InputError(MbdfmuError):
    """An unknown input name, a non-finite input value, an unreadable input table, or a
    scene given to ``Simulation`` as something other than a Scene, a path or a name."""


def suggest(word: str, choices) -> str:
    """' (did you mean "x"?)' for the closest of ``choices``, or ''."""
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f' (did you mean "{close[0]}"?)' if close else ""


class Problems:
    """Collects located problems of one source; ``raise_if_any`` raises them all at once."""

    def __init__(self, source: str, error: type[ReadError] = SceneError):
        self.source, self.error = source, error
        self.items: list[str] = []

    def add(self, where: str, what: str) -> None:
        self.items.append(f"{self.source}: {where}: {what}" if where else f"{self.source}: {what}")

    def raise_if_any(self) -> None:
        if self.items:
            raise self.error(self.items)
