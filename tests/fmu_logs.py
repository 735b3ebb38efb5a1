"""The FMU log messages of every fmpy instance in this test process, by instance name.

fmpy's native logger proxy (which formats the FMU's variadic messages) keeps one Python
logger per process, and its default callbacks go through that proxy too. So the tests
register one logger, kept alive for the whole process, the first time this module is
imported; a logger= given to fmpy.simulate_fmu would replace it with a callback freed when
simulate_fmu returns, after which the next FMU that logs crashes the process.
"""

from __future__ import annotations

from ctypes import byref

from fmpy.fmi1 import calloc, free
from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.logging import addLoggerProxy

LOGS: dict[str, list[tuple[int, str, str]]] = {}


def _log(env, instance, status, category, message):
    LOGS.setdefault(instance.decode(), []).append(
        (status, (category or b"").decode(), message.decode()))


CALLBACKS = fmi2CallbackFunctions()
CALLBACKS.logger = fmi2CallbackLoggerTYPE(_log)
CALLBACKS.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
CALLBACKS.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(byref(CALLBACKS))


def take(instance: str) -> list[str]:
    """The messages logged so far by ``instance`` (its text only), forgetting them."""
    return [text for _, _, text in LOGS.pop(instance, [])]
