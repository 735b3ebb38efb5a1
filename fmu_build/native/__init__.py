"""Compile ``fmi2.c`` into the binary every mbdfmu FMU ships (``binaries/linux64/<id>.so``).

The binary holds nothing model-specific, so it is compiled once per source, headers,
compiler and flags, and cached: ``compile_wrapper()`` returns the cached file when the key
(a SHA-256 of all four) has been built before.

The FMI 2.0 headers come from fmpy (``fmpy/c-code``), which mbdfmu depends on anyway;
they are not copied into this repository.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

SOURCE = Path(__file__).with_name("fmi2.c")
HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")
# -fvisibility=hidden: only the fmi2* functions (marked FMI2_Export) are exported.
# --no-undefined: proves the binary needs nothing beyond libc and libdl (no libpython).
FLAGS = ("-shared", "-fPIC", "-O2", "-std=gnu11", "-Wall", "-Wextra", "-fvisibility=hidden",
         "-Wl,--no-undefined")
LIBS = ("-ldl", "-lpthread")
ENV_CACHE = "MBDFMU_CACHE_DIR"


class CompileError(RuntimeError):
    """The wrapper could not be built (the message is one line: what to install or fix)."""


def default_cache_dir() -> Path:
    """``$MBDFMU_CACHE_DIR``, else ``$XDG_CACHE_HOME/mbdfmu``, else ``~/.cache/mbdfmu``."""
    if os.environ.get(ENV_CACHE):
        return Path(os.environ[ENV_CACHE])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "mbdfmu"


def find_compiler() -> str:
    """``$CC`` or the first of gcc, cc, clang on PATH; CompileError if there is none."""
    candidates = [os.environ["CC"]] if os.environ.get("CC") else ["gcc", "cc", "clang"]
    for name in candidates:
        path = shutil.which(name)
        if path:
            return path
    raise CompileError(f"no C compiler found (looked for {', '.join(candidates)}): install one "
                       "(Debian/Ubuntu: apt-get install gcc) or set CC to its path")


def header_dir() -> Path:
    """fmpy's folder of FMI headers; CompileError if fmpy is not installed."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or not spec.submodule_search_locations:
        raise CompileError("the FMI 2.0 headers come from fmpy, which is not installed: "
                           "pip install fmpy")
    folder = Path(list(spec.submodule_search_locations)[0]) / "c-code"
    missing = [h for h in HEADERS if not (folder / h).is_file()]
    if missing:
        raise CompileError(f"fmpy's {folder} lacks {', '.join(missing)}: reinstall fmpy")
    return folder


def cache_key(compiler: str, headers: Path) -> str:
    """SHA-256 over the source, the headers, the compiler's identity and the flags."""
    digest = hashlib.sha256()
    for path in (SOURCE, *(headers / h for h in HEADERS)):
        digest.update(path.read_bytes())
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True).stdout
    digest.update(f"{compiler}\n{version}\n{FLAGS}\n{LIBS}".encode())
    return digest.hexdigest()


def compile_wrapper(cache_dir: str | os.PathLike | None = None) -> Path:
    """The compiled wrapper, built now or taken from ``cache_dir`` (see ``default_cache_dir``)."""
    compiler = find_compiler()
    headers = header_dir()
    key = cache_key(compiler, headers)
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = folder / f"mbdfmu-fmi2-{key[:24]}.so"
    if target.is_file():
        return target
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        built = Path(tmp) / target.name
        command = [compiler, *FLAGS, f"-I{headers}", "-o", str(built), str(SOURCE), *LIBS]
        run = subprocess.run(command, capture_output=True, text=True)
        if run.returncode != 0:
            first = (run.stderr.strip().splitlines() or ["(no output)"])[0]
            raise CompileError(f"compiling {SOURCE.name} failed: {first}")
        os.replace(built, target)   # atomic: a concurrent build never sees half a file
    return target
