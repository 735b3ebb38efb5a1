"""What every mbdfmu FMU build shares: content digests, filling a model template, and
writing the FMU with one kind of error (``BuildError``, one line) for every failure."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from ..errors import MbdfmuError

GENERATED = re.compile(r"(# >>> GENERATED[^\n]*\n)(.*?)(# <<< GENERATED\n)", re.S)


class BuildError(MbdfmuError):
    """A scene or companion source that cannot be turned into an FMU (the message says why)."""


def digest(*chunks: bytes) -> str:
    """A short content hash that tells FMU modules apart (length-prefixed chunks)."""
    h = hashlib.sha256()
    for c in chunks:
        h.update(len(c).to_bytes(8, "little"))
        h.update(c)
    return h.hexdigest()[:12]


def fill_template(template: Path, values: dict) -> str:
    """``template``'s text with its GENERATED block replaced by ``NAME = repr(value)`` lines."""
    block = "".join(f"{name} = {value!r}\n" for name, value in values.items())
    text, n = GENERATED.subn(lambda m: m.group(1) + block + m.group(3),
                             template.read_text(encoding="utf-8"))
    if n != 1:
        raise BuildError(f"{template}: the GENERATED block is missing")
    return text


def fmu_path(output, identifier: str) -> Path:
    """Where to write: ``output``, or ``<identifier>.fmu`` in the cwd; must end in .fmu."""
    path = Path(output) if output is not None else Path.cwd() / f"{identifier}.fmu"
    if path.suffix != ".fmu":
        raise BuildError(f"{path}: an FMU file name must end in .fmu")
    return path


def write_checked(output, identifier: str, variables, source: str, **options) -> Path:
    """``package.write_fmu`` with its failures (no C compiler, no fmpy headers, a table or
    source FMI cannot express) as one-line ``BuildError``s."""
    from .model_description import ModelDescriptionError
    from .native import CompileError
    from .package import PackageError, write_fmu
    from .runtime.variables import VariableError

    path = fmu_path(output, identifier)
    try:
        return write_fmu(path, identifier, variables, source, **options)
    except CompileError as exc:
        raise BuildError(f"cannot build the FMU's binary: {exc}") from None
    except (PackageError, ModelDescriptionError, VariableError) as exc:
        raise BuildError(f"{identifier}: {exc}") from None
