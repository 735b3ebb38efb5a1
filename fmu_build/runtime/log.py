"""Log messages of one instance, queued for the C wrapper to pass to the host's logger.

Every message has a status, a category and a text. The categories are the FMU's
``LogCategories`` (written into the model description):

* ``logStatusWarning``, ``logStatusDiscard``, ``logStatusError``, ``logStatusFatal``: the
  reason for a call that returned that status. They are on even when the master
  instantiated with loggingOn = false, because they are not debug output: they say why
  a call failed. A master silences them only by naming them in
  ``fmi2SetDebugLogging(false, n, names)``.
* ``logAll`` and the model's own categories: debug output, on when loggingOn = true.

``fmi2SetDebugLogging(on, 0, NULL)`` switches every debug category; with names, only
those. ``logAll`` enabled forwards everything.
"""

from __future__ import annotations

from . import status

STATUS_CATEGORIES = {
    status.WARNING: "logStatusWarning", status.DISCARD: "logStatusDiscard",
    status.ERROR: "logStatusError", status.FATAL: "logStatusFatal",
}
STANDARD_CATEGORIES = {
    "logStatusWarning": "Reasons for calls that returned fmi2Warning",
    "logStatusDiscard": "Reasons for calls that returned fmi2Discard",
    "logStatusError": "Reasons for calls that returned fmi2Error",
    "logStatusFatal": "Reasons for calls that returned fmi2Fatal",
    "logAll": "Every message, including debug output",
}
# Most messages kept between two FMI calls (a model logging in a loop cannot exhaust memory).
MAX_PENDING = 1000


class LogQueue:
    """The pending messages of one instance and which categories are on.

    ``pending`` is a plain list of ``(status, category, text)``: the C wrapper checks its
    length after each call (cheap) and calls ``take`` only when it is not empty.
    """

    def __init__(self, model_categories: dict[str, str], logging_on: bool, translate=None):
        self.translate = translate      # FMI 3.0: names in messages (fmi3.fmi3_text)
        self.categories = {**STANDARD_CATEGORIES, **model_categories}
        self.debug = set(self.categories) - set(STATUS_CATEGORIES.values())
        self.enabled = set(STATUS_CATEGORIES.values()) | (self.debug if logging_on else set())
        self.pending: list[tuple[int, str, str]] = []

    def set_debug_logging(self, logging_on: bool, names: tuple[str, ...]) -> str | None:
        """Apply fmi2SetDebugLogging; the reason when a name is unknown (nothing changed)."""
        unknown = [n for n in names if n not in self.categories]
        if unknown:
            return (f"fmi2SetDebugLogging: unknown log categories {', '.join(map(repr, unknown))}; "
                    f"this FMU has {', '.join(self.categories)}")
        chosen = set(names) if names else self.debug
        self.enabled = self.enabled | chosen if logging_on else self.enabled - chosen
        return None

    def emit(self, code: int, category: str, text: str) -> None:
        """Queue ``text`` when its category (or logAll) is enabled."""
        if (category in self.enabled or "logAll" in self.enabled) and len(self.pending) < MAX_PENDING:
            self.pending.append((code, category, self.translate(text) if self.translate else text))

    def status(self, code: int, text: str) -> None:
        """Queue the reason for a call that returns ``code`` (Warning and worse)."""
        self.emit(code, STATUS_CATEGORIES.get(code, "logAll"), text)

    def take(self) -> list[tuple[int, str, str]]:
        """The pending messages, oldest first; the queue is emptied."""
        taken, self.pending[:] = list(self.pending), []
        return taken
