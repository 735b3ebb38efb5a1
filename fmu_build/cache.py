"""FMUs built once and reused while their sources (and the tools that build them) are
unchanged: a scenario's FMUs, keyed by a SHA-256 of everything that goes into them."""

from __future__ import annotations

import hashlib
from pathlib import Path

from . import build
from .scene_fmu import wants_scene_kernel

HERE = Path(__file__).resolve().parent


def _tree_digest(*roots: Path) -> bytes:
    h = hashlib.sha256()
    for root in roots:
        files = [root] if root.is_file() else sorted(
            p for p in root.rglob("*")
            if p.suffix in (".py", ".c") and "__pycache__" not in p.parts)
        for f in files:
            h.update(str(f.name).encode() + b"\0" + f.read_bytes())
    return h.digest()


def _tools_digest(kind: str) -> bytes:
    """What else goes into an FMU of this kind: this package (the builders, the runtime,
    the native wrapper's source) and, for scenes, the mbdfmu core."""
    if kind == ".py":
        return _tree_digest(HERE)
    from .scene_fmu import core_init
    return _tree_digest(Path(core_init).resolve().parent, HERE)


def build_fmus(sources: dict[str, Path], folder: str | Path,
               fmi_version: int = 2) -> dict[str, Path]:
    """Build (or reuse) the FMU (FMI ``fmi_version``.0) of each ``{instance: source}`` in
    ``folder``; returns ``{instance: fmu}``. Instances of one source share one FMU, named
    after the source (``slider_crank.fmu``, ``slider_crank.fmi3.fmu``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    built: dict[Path, Path] = {}
    tools: dict[str, bytes] = {}
    for src in dict.fromkeys(sources.values()):
        kind = src.suffix
        if kind not in tools:
            tools[kind] = _tools_digest(kind)
        # a scene's FMU with or without the kernel built for it ($MBDFMU_SCENE_KERNEL)
        kernel = str(wants_scene_kernel(None)).encode() if kind == ".toml" else b""
        digest = hashlib.sha256(tools[kind] + src.read_bytes() + str(fmi_version).encode()
                                + kernel).hexdigest()
        fmu = folder / f"{src.stem}{'.fmi3' if fmi_version == 3 else ''}.fmu"
        stamp = fmu.with_name(fmu.name + ".sha256")
        if not (fmu.is_file() and stamp.is_file() and stamp.read_text().strip() == digest):
            build(src, fmu, fmi_version=fmi_version)
            stamp.write_text(digest + "\n")
        built[src] = fmu
    return {name: built[src] for name, src in sources.items()}
