"""Compile the wrapper every mbdfmu FMU ships (``binaries/linux64/<id>.so``): ``fmi2.c``
for FMI 2.0 FMUs, ``fmi3.c`` for FMI 3.0 ones, both on ``bridge.h`` (finding Python, the
call protocol with the runtime, states).

The binary holds nothing model-specific, so it is compiled once per FMI version, source,
headers, compiler and flags, and cached: ``compile_wrapper()`` returns the cached file
when the key (a SHA-256 of all of them) has been built before.

The FMI headers come from fmpy (``fmpy/c-code``), which mbdfmu depends on anyway; they
are not copied into this repository.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCES = {2: HERE / "fmi2.c", 3: HERE / "fmi3.c"}
BRIDGE = HERE / "bridge.h"
HEADERS = {2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
           3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")}
# -fvisibility=hidden: only the fmi2*/fmi3* functions (marked FMI2_Export/FMI3_Export) are
# exported.
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


def header_dir(fmi_version: int = 2) -> Path:
    """fmpy's folder of FMI headers; CompileError if fmpy is not installed."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or not spec.submodule_search_locations:
        raise CompileError(f"the FMI {fmi_version}.0 headers come from fmpy, which is not "
                           "installed: pip install fmpy")
    folder = Path(list(spec.submodule_search_locations)[0]) / "c-code"
    missing = [h for h in HEADERS[fmi_version] if not (folder / h).is_file()]
    if missing:
        raise CompileError(f"fmpy's {folder} lacks {', '.join(missing)}: reinstall fmpy")
    return folder


def cache_key(compiler: str, headers: Path, fmi_version: int = 2) -> str:
    """SHA-256 over the sources, the headers, the compiler's identity and the flags."""
    digest = hashlib.sha256()
    for path in (SOURCES[fmi_version], BRIDGE, *(headers / h for h in HEADERS[fmi_version])):
        digest.update(path.read_bytes())
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True).stdout
    digest.update(f"{compiler}\n{version}\n{FLAGS}\n{LIBS}".encode())
    return digest.hexdigest()


def compile_wrapper(cache_dir: str | os.PathLike | None = None, fmi_version: int = 2) -> Path:
    """The compiled wrapper of FMI version ``fmi_version`` (2 or 3), built now or taken from
    ``cache_dir`` (see ``default_cache_dir``)."""
    if fmi_version not in SOURCES:
        raise CompileError(f"FMI version {fmi_version!r}: mbdfmu builds FMI 2.0 and 3.0 FMUs")
    compiler = find_compiler()
    headers = header_dir(fmi_version)
    key = cache_key(compiler, headers, fmi_version)
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = folder / f"mbdfmu-fmi{fmi_version}-{key[:24]}.so"
    if target.is_file():
        return target
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        built = Path(tmp) / target.name
        source = SOURCES[fmi_version]
        command = [compiler, *FLAGS, f"-I{headers}", f"-I{HERE}", "-o", str(built), str(source),
                   *LIBS]
        run = subprocess.run(command, capture_output=True, text=True)
        if run.returncode != 0:
            first = (run.stderr.strip().splitlines() or ["(no output)"])[0]
            raise CompileError(f"compiling {source.name} failed: {first}")
        os.replace(built, target)   # atomic: a concurrent build never sees half a file
    return target
