"""Build a companion FMU (a DC motor, a hydraulic cylinder, ...) from its Python source.

A companion source imports its base class as

    from mbdfmu.fmu_build import companion_base as base

so it runs and can be tested in Python as it is. The FMU ships a copy of that base under a
name unique to its content (``_mbdfmu_companion_base_<hash>``) with the import rewritten, and
the source itself as ``mbdfmu_<stem>_<hash>``: pythonfmu caches an FMU's module by name in
the host, so two companions (or two versions of one) never share a module, and neither
depends on an mbdfmu installed in the host (docs/fmu.md).
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from .common import CAPABILITIES, BuildError, build_isolated, digest

BASE = Path(__file__).resolve().parent / "companion_base.py"
# The import line a companion source uses for its base class (rewritten in the FMU).
BASE_IMPORT = re.compile(r"^from mbdfmu\.fmu_build import companion_base as base[ \t]*$",
                         re.M)


def build_companion(source, output=None) -> Path:
    """Build the FMU of a companion source; returns its path (default ``<Class>.fmu`` in
    the cwd, the class name being the model identifier)."""
    source = Path(source)
    if not source.is_file():
        raise BuildError(f"{source}: no such file")
    text = source.read_text(encoding="utf-8")
    base_text = BASE.read_bytes()
    base_module = f"_mbdfmu_companion_base_{digest(base_text)}"
    text, uses_base = BASE_IMPORT.subn(f"import {base_module} as base", text)
    module = f"mbdfmu_{re.sub(r'[^A-Za-z0-9_]', '_', source.stem)}_" \
             f"{digest(text.encode(), base_text)}"
    if output is not None:
        output = Path(output)
        if output.suffix != ".fmu":
            raise BuildError(f"{output}: an FMU file name must end in .fmu")
        output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="mbdfmu_companion_") as tmp:
        stage = Path(tmp)
        script = stage / f"{module}.py"
        script.write_text(text, encoding="utf-8")
        project_files = []
        if uses_base:
            (stage / f"{base_module}.py").write_bytes(base_text)
            project_files.append(stage / f"{base_module}.py")
        try:
            fmu = build_isolated(script, dest=output if output is not None else Path.cwd(),
                                 own_modules={module, base_module},
                                 project_files=project_files, **CAPABILITIES)
        except (ValueError, TypeError, AttributeError, ImportError, SyntaxError) as exc:
            raise BuildError(f"{source}: {type(exc).__name__}: {exc}") from None
    return Path(fmu)

