"""The project's errors: one small hierarchy, caught once at each boundary (CLI, FMU)."""

from __future__ import annotations


class MbdfmuError(Exception):
    """Base of every error mbdfmu raises on purpose."""


class SceneError(MbdfmuError):
    """A scene file that cannot be read, or a scene that cannot be built.

    ``problems`` lists every problem found, each already located
    (``slider_crank.toml: joint "A": unknown body "rodd" (did you mean "rod"?)``).
    """

    def __init__(self, problems: list[str] | str):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("; ".join(self.problems))


class AssemblyError(SceneError):
    """Initial positions or velocities that cannot be made to satisfy the constraints."""


class SolverError(MbdfmuError):
    """An integration that cannot go on: time and reason are in the message."""

    def __init__(self, message: str, t: float | None = None):
        self.t = t
        prefix = f"t = {t:.9g} s: " if t is not None else ""
        super().__init__(prefix + message)


class InputError(MbdfmuError):
    """An unknown input name, a non-finite input value, or an unreadable input table."""
