"""The FMUs of a scenario, built once and reused while their sources are unchanged."""

from __future__ import annotations

import hashlib
from pathlib import Path

from .companion import build
from .scenario import Scenario

HERE = Path(__file__).resolve().parent


def _tree_digest(*roots: Path) -> bytes:
    h = hashlib.sha256()
    for root in roots:
        files = [root] if root.is_file() else sorted(
            p for p in root.rglob("*.py") if "__pycache__" not in p.parts)
        for f in files:
            h.update(str(f.name).encode() + b"\0" + f.read_bytes())
    return h.digest()


def _tools_digest(kind: str) -> bytes:
    """What else goes into an FMU of this kind: the mbdfmu core and fmu_build for scenes,
    the companion base and builder for companion sources."""
    if kind == ".py":
        return _tree_digest(HERE / "companion_base.py", HERE / "companion.py")
    import fmu_build

    return _tree_digest(HERE.parent, Path(fmu_build.__file__).resolve().parent)


def build_fmus(scenario: Scenario, folder: str | Path) -> dict[str, Path]:
    """Build (or reuse) each instance's FMU in ``folder``: ``{instance: path}``. Instances
    of one source share one FMU, named after the source (``slider_crank.fmu``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    built: dict[Path, Path] = {}
    tools: dict[str, bytes] = {}
    for inst in scenario.instances:
        src = inst.source
        if src not in built:
            kind = src.suffix
            if kind not in tools:
                tools[kind] = _tools_digest(kind)
            digest = hashlib.sha256(tools[kind] + src.read_bytes()).hexdigest()
            fmu = folder / f"{src.stem}.fmu"
            stamp = folder / f"{src.stem}.fmu.sha256"
            if not (fmu.is_file() and stamp.is_file() and stamp.read_text().strip() == digest):
                build(src, fmu)
                stamp.write_text(digest + "\n")
            built[src] = fmu
    return {inst.name: built[inst.source] for inst in scenario.instances}
