"""Options shared by the CLI's commands: ``--set``, progress bars, warning lines.

``--set NAME=VALUE`` takes the FMU's parameter names (``crank.mass``, ``gravity.y``,
``motor.rate``, ``solver.rtol``) with the FMU's checks (``model.variables.with_parameters``
for the scene's parameters, ``SolverSettings`` for ``solver.*``); the sweep's
``NAME=START:STOP:COUNT`` gives COUNT values from START to STOP.
"""

from __future__ import annotations

import math
import sys
import threading

import numpy as np

from .errors import SettingError

SOLVER_PARAMETERS = ("solver.method", "solver.step", "solver.rtol", "solver.atol")


def _split(text: str, flag: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise SettingError(flag, f"{flag} {text!r}: expected NAME=VALUE (a parameter name as "
                           "the FMU's, e.g. crank.mass=0.3)")
    return name.strip(), value.strip()


def _number(text: str, flag: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SettingError(flag, f"{flag} {name}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise SettingError(flag, f"{flag} {name}: {text!r} is not finite")
    return value


def parse_assignments(texts: list[str] | None, flag: str = "--set") -> dict[str, object]:
    """``NAME=VALUE`` items as {name: value}: numbers, except ``solver.method`` (a name)."""
    values: dict[str, object] = {}
    for text in texts or []:
        name, value = _split(text, flag)
        if name in values:
            raise SettingError(flag, f"{flag} {name} is given twice")
        values[name] = value if name == "solver.method" else _number(value, flag, name)
    return values


def parse_ranges(texts: list[str] | None, flag: str = "--set") -> dict[str, np.ndarray]:
    """``NAME=START:STOP:COUNT`` (or ``NAME=VALUE``) items as {name: values}."""
    ranges: dict[str, np.ndarray] = {}
    for text in texts or []:
        name, spec = _split(text, flag)
        parts = spec.split(":")
        if len(parts) not in (1, 3):
            raise SettingError(flag, f"{flag} {name}={spec}: expected START:STOP:COUNT or VALUE")
        if name in ranges:
            raise SettingError(flag, f"{flag} {name} is given twice")
        if len(parts) == 1:
            ranges[name] = np.array([_number(parts[0], flag, name)])
            continue
        start, stop = (_number(p, flag, name) for p in parts[:2])
        try:
            count = int(parts[2])
        except ValueError:
            count = 0
        if count < 1 or str(count) != parts[2].strip():
            raise SettingError(flag, f"{flag} {name}: COUNT must be a whole number of at least "
                               f"1, got {parts[2]!r}")
        ranges[name] = np.linspace(start, stop, count)
    if not ranges:
        raise SettingError(flag, f"give at least one {flag} NAME=START:STOP:COUNT")
    return ranges


def split_solver(values: dict[str, object]) -> tuple[dict[str, float], dict[str, object]]:
    """(scene parameters, SolverSettings fields) of ``--set`` values."""
    scene = {k: v for k, v in values.items() if not k.startswith("solver.")}
    solver = {k[len("solver."):]: v for k, v in values.items() if k.startswith("solver.")}
    unknown = [f"solver.{k}" for k in solver if f"solver.{k}" not in SOLVER_PARAMETERS]
    if unknown:
        raise SettingError("--set", f"--set {unknown[0]}: unknown; solver parameters: "
                           f"{', '.join(SOLVER_PARAMETERS)}")
    return scene, solver


SOLVER_NAMES = {k: f"--set solver.{k}" for k in ("method", "step", "rtol", "atol")}


def show_progress(args) -> bool:
    """Progress bars on, unless --no-progress or stdout is not a terminal."""
    return not getattr(args, "no_progress", False) and sys.stdout.isatty()


def progress_bar(args, total: float, desc: str, unit: str):
    """A tqdm bar on stderr (disabled per ``show_progress``)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=not show_progress(args),
                file=sys.stderr, leave=False, dynamic_ncols=True,
                bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} {unit} [{elapsed}<{remaining}]"
                if unit == "s" else None)


class Ticker:
    """An elapsed-time bar for work whose fraction done is unknown (a build, a
    co-simulation run by another library): ``with Ticker(args, "cosim"): ...``."""

    def __init__(self, args, desc: str):
        self.args, self.desc = args, desc
        self._stop = threading.Event()

    def __enter__(self):
        if show_progress(self.args):
            from tqdm import tqdm
            self._bar = tqdm(desc=self.desc, total=None, file=sys.stderr, leave=False,
                             bar_format="{desc}: {elapsed} elapsed")
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()
        return self

    def _run(self):
        while not self._stop.wait(0.5):
            self._bar.refresh()

    def __exit__(self, *exc):
        self._stop.set()
        if hasattr(self, "_thread"):
            self._thread.join()
            self._bar.close()
        return False


def print_warnings(command: str, lines: list[str]) -> None:
    for line in lines:
        print(f"mbdfmu {command}: warning: {line}", file=sys.stderr)


def add_set_option(parser, what: str = "parameter") -> None:
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help=f"set a {what} (names as the FMU's parameters: crank.mass, "
                        "gravity.y, motor.rate, spring.stiffness, solver.rtol; repeatable)")


def add_progress_option(parser) -> None:
    parser.add_argument("--no-progress", action="store_true",
                        help="no progress bar (also off when stdout is not a terminal)")
