"""What every mbdfmu FMU build shares: capability flags, content digests, and running
pythonfmu's builder without leaving traces in this process."""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

from ..errors import MbdfmuError

# What every mbdfmu FMU advertises: masters may roll back, serialize and vary the step.
CAPABILITIES = dict(needsExecutionTool=True, canHandleVariableCommunicationStepSize=True,
                    canGetAndSetFMUstate=True, canSerializeFMUstate=True,
                    canInterpolateInputs=False, canBeInstantiatedOnlyOncePerProcess=False)


class BuildError(MbdfmuError):
    """A scene or companion source that cannot be turned into an FMU (the message says why)."""


def digest(*chunks: bytes) -> str:
    """A short content hash that tells FMU modules apart (length-prefixed chunks)."""
    h = hashlib.sha256()
    for c in chunks:
        h.update(len(c).to_bytes(8, "little"))
        h.update(c)
    return h.hexdigest()[:12]


def build_isolated(script: Path, dest: Path, own_modules: set[str], **options) -> Path:
    """pythonfmu's ``build_FMU``, leaving this process as it found it.

    pythonfmu imports the script (and what it ships) in this process and leaves its folder
    on ``sys.path``: both are undone (for the FMU's own modules only; third-party modules
    imported on the way stay), so this process later loads the FMU's own copy.
    """
    from pythonfmu.builder import FmuBuilder

    saved_path, saved_modules = list(sys.path), set(sys.modules)
    try:
        return Path(FmuBuilder.build_FMU(script, dest=dest, **options))
    finally:
        sys.path[:] = saved_path
        for m in set(sys.modules) - saved_modules:
            if m.split(".")[0] in own_modules:
                del sys.modules[m]
