"""Compiling the C kernel (``kernel.c`` with its headers, SOURCES) into a shared library.

``compile_kernel()`` builds it once per content (sources, compiler, flags: a SHA-256 names
the file) into the per-user cache (``$MBDFMU_CACHE_DIR``, else ``$XDG_CACHE_HOME/mbdfmu``,
else ``~/.cache/mbdfmu``) and returns its path; ``mbdfmu build`` ships that file in the FMU,
so nothing is compiled when an FMU is loaded. ``KernelBuildError`` says in one line why it
could not be built (no compiler, a compiler error).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCES = ("kernel.c", "solve.h", "nullspace.h", "friction.h", "events.h", "stepping.h",
           "outputs.h", "dense.h", "motions.h", "fixed.h", "adaptive.h", "dense_run.h",
           "implicit.h", "implicit_dense.h", "implicit_run.h")
# -O2 without -ffast-math and without contracting a * b + c into one fused operation: the
# kernel must round like the numpy code it translates, on any target.
CFLAGS = ("-O2", "-shared", "-fPIC", "-std=gnu11", "-fno-fast-math", "-ffp-contract=off",
          "-Wall")
# A kernel built for one scene (scene_kernel.py): -O3 unrolls its constant loops; it changes
# no rounding (no reassociation without -ffast-math).
SCENE_CFLAGS = ("-O3",) + CFLAGS[1:]
SCENE_HEADER = "mbdfmu_scene.h"


class KernelBuildError(RuntimeError):
    """The kernel could not be compiled (one line: what to install or fix)."""


def source_digest() -> str:
    """SHA-256 of the kernel's sources: the name a built library carries."""
    h = hashlib.sha256()
    for name in SOURCES:
        h.update(name.encode() + b"\0" + (HERE / name).read_bytes())
    return h.hexdigest()


def cache_dir() -> Path:
    if os.environ.get("MBDFMU_CACHE_DIR"):
        return Path(os.environ["MBDFMU_CACHE_DIR"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mbdfmu"


def compile_kernel(folder: str | os.PathLike | None = None, *,
                   scene_header: str | None = None) -> Path:
    """The compiled kernel, built now or found in ``folder`` (default ``cache_dir()``);
    with ``scene_header`` (scene_kernel.py's), the kernel built for that scene."""
    names = [os.environ["CC"]] if os.environ.get("CC") else ["gcc", "cc", "clang"]
    compiler = next(filter(None, map(shutil.which, names)), None)
    if compiler is None:
        raise KernelBuildError(f"no C compiler found (looked for {', '.join(names)}): the "
                               "numpy kernel runs instead")
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True).stdout
    flags = CFLAGS if scene_header is None else SCENE_CFLAGS
    key = hashlib.sha256(f"{source_digest()}\n{compiler}\n{version}\n{flags}\n"
                         f"{scene_header or ''}".encode())
    kind = "kernel" if scene_header is None else "scene-kernel"
    target = Path(folder or cache_dir()) / f"mbdfmu-{kind}-{key.hexdigest()[:24]}.so"
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        built = Path(tmp) / target.name
        scene = []
        if scene_header is not None:
            (Path(tmp) / SCENE_HEADER).write_text(scene_header)
            scene = [f'-DMBD_SCENE="{SCENE_HEADER}"', "-I", tmp]
        run = subprocess.run([compiler, *flags, *scene, "-o", str(built), str(HERE / SOURCES[0]),
                              "-lm"], capture_output=True, text=True)
        if run.returncode != 0:
            first = (run.stderr.strip().splitlines() or ["(no output)"])[0]
            raise KernelBuildError(f"compiling the C kernel failed: {first}")
        os.replace(built, target)      # atomic: a concurrent build never sees half a file
    return target
