"""Assemble an FMI 2.0 co-simulation FMU around the native wrapper: ``write_fmu``.

The .fmu (a zip) holds::

    modelDescription.xml                 from the variable table (model_description.py)
    binaries/linux64/<id>.so             the compiled fmi2.c, the same for every FMU
    resources/mbdfmu.json                what the wrapper and the runtime read (below)
    resources/mbdfmu_boot.py             run by the wrapper at fmi2Instantiate
    resources/mbdfmu_fmi2_<hash>/        the runtime package (fmu_build/runtime)
    resources/model_<hash>.py            the model module (a Slave subclass)
    resources/...                        extra resources of the model

``mbdfmu.json``: ``format``, ``model_identifier``, ``guid``, ``python_library`` (the
libpython to load in a host without Python), ``python_home`` (its ``sys.base_prefix``,
where its standard library is), ``python_version``, ``site_dirs`` (where the
build's numpy and scipy live), ``runtime_package``, ``model_module``, ``model_class``,
``variables``, ``log_categories``, ``default_experiment``.

Module names carry a hash of their content: several FMUs share one interpreter in a
process, and a module is imported once per name.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import site
import sys
import sysconfig
import tempfile
import uuid
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

from .model_description import Capabilities, DefaultExperiment, ModelInfo, model_description
from .native import compile_wrapper
from .runtime.variables import VariableTable

RUNTIME_DIR = Path(__file__).with_name("runtime")
BOOT_FILE = "boot.py"
CONFIG_NAME = "mbdfmu.json"
CONFIG_FORMAT = 1
# Fixed zip timestamp: the same inputs give the same .fmu bytes.
ZIP_TIME = (1980, 1, 1, 0, 0, 0)
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class PackageError(ValueError):
    """Inputs ``write_fmu`` cannot turn into an FMU (the message says which and why)."""


@dataclass(frozen=True)
class PythonEnvironment:
    """The Python an FMU falls back to in a host that has none (recorded at build time)."""

    library: str | None
    home: str
    version: str
    site_dirs: tuple[str, ...]

    @classmethod
    def current(cls) -> "PythonEnvironment":
        """This interpreter: its shared libpython, version, and site folders (with numpy's)."""
        dirs = list(site.getsitepackages())
        if site.ENABLE_USER_SITE:
            dirs.append(site.getusersitepackages())
        import numpy   # where numpy was found (it may be on PYTHONPATH, not in a site dir)
        dirs.append(str(Path(numpy.__file__).resolve().parents[1]))
        unique = tuple(dict.fromkeys(d for d in dirs if Path(d).is_dir()))
        version = ".".join(map(str, sys.version_info[:3]))
        return cls(shared_libpython(), sys.base_prefix, version, unique)


def shared_libpython() -> str | None:
    """Path of this interpreter's libpython3.X.so.1.0, or None (a static build without one)."""
    names = [sysconfig.get_config_var(k) for k in ("INSTSONAME", "LDLIBRARY")]
    folders = [sysconfig.get_config_var("LIBDIR")]
    if sysconfig.get_config_var("MULTIARCH"):
        folders.append(os.path.join("/usr/lib", sysconfig.get_config_var("MULTIARCH")))
    for folder in filter(None, folders):
        for name in filter(None, names):
            path = Path(folder) / name
            if name.endswith((".so", ".so.1.0")) and path.is_file():
                return str(path)
    return None


def runtime_files() -> dict[str, bytes]:
    """The runtime package's files (name -> content); boot.py is also shipped alone, as
    resources/mbdfmu_boot.py, which the wrapper runs first."""
    return {p.name: p.read_bytes() for p in sorted(RUNTIME_DIR.glob("*.py"))}


def _digest(*parts: bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(hashlib.sha256(part).digest())
    return h.hexdigest()


def _extra_files(extra_resources) -> dict[str, bytes]:
    """Flatten ``extra_resources`` (name -> bytes, str or path of a file or folder)."""
    files: dict[str, bytes] = {}
    for name, content in (extra_resources or {}).items():
        relative = Path(name)
        if relative.is_absolute() or ".." in relative.parts or not relative.parts:
            raise PackageError(f'extra resource "{name}": must be a relative path inside resources/')
        if isinstance(content, (bytes, str)):
            files[relative.as_posix()] = content if isinstance(content, bytes) else content.encode()
        elif Path(content).is_dir():
            for path in sorted(Path(content).rglob("*")):
                if path.is_file() and "__pycache__" not in path.parts:
                    files[(relative / path.relative_to(content)).as_posix()] = path.read_bytes()
        elif Path(content).is_file():
            files[relative.as_posix()] = Path(content).read_bytes()
        else:
            raise PackageError(f'extra resource "{name}": {content!r} is not bytes, text or a file')
    return files


def _check_inputs(model_identifier: str, variables, model_module_source: str) -> VariableTable:
    if not IDENTIFIER.fullmatch(model_identifier):
        raise PackageError(f'model identifier "{model_identifier}" is not a C identifier')
    if not isinstance(model_module_source, str) or not model_module_source.strip():
        raise PackageError("the model module source is empty")
    try:
        compile(model_module_source, "<model module>", "exec")
    except SyntaxError as exc:
        raise PackageError(f"the model module does not compile: {exc}") from None
    return VariableTable(tuple(variables))


def _zip(output: Path, members: dict[str, bytes]) -> None:
    """Write the zip atomically, members sorted, with fixed timestamps."""
    output.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=output.parent, suffix=".fmu.tmp")
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as fmu:
            for name in sorted(members):
                info = zipfile.ZipInfo(name, ZIP_TIME)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = (0o755 if name.startswith("binaries/") else 0o644) << 16
                fmu.writestr(info, members[name])
        os.replace(tmp, output)
    except BaseException:
        os.unlink(tmp)
        raise


def write_fmu(output, model_identifier: str, variables, model_module_source: str, *,
              model_class: str = "Model", model_name: str | None = None, description: str = "",
              info: ModelInfo | None = None,
              extra_resources=None, capabilities: Capabilities = Capabilities(),
              default_experiment: DefaultExperiment | None = DefaultExperiment(),
              log_categories: dict[str, str] | None = None,
              python: PythonEnvironment | None = None, binary=None, cache_dir=None) -> Path:
    """Write an FMI 2.0 co-simulation FMU to ``output`` and return its path.

    ``variables``: ``Variable`` objects (the one table of value references); ``info``:
    author, version, generation tool (and the description, overriding ``description``);
    ``model_module_source``: Python source defining ``model_class``, a subclass of the
    runtime's ``Slave`` imported with ``from . import Slave``; ``extra_resources``: name
    under resources/ -> bytes, text, or the path of a file or folder; ``log_categories``:
    the model's own categories (name -> description); ``python``: the environment recorded
    for hosts without Python (default: this interpreter); ``binary``: a compiled wrapper
    (default: ``compile_wrapper(cache_dir)``). The GUID is a digest of everything shipped,
    so the same inputs give the same FMU, and a state serialized by one build loads into
    the same build only.
    """
    table = _check_inputs(model_identifier, variables, model_module_source)
    python = python or PythonEnvironment.current()
    binary_bytes = Path(binary or compile_wrapper(cache_dir)).read_bytes()
    runtime = runtime_files()
    runtime_package = "mbdfmu_fmi2_" + _digest(*(k.encode() + v for k, v in runtime.items()))[:16]
    model_module = "model_" + _digest(model_module_source.encode())[:16]
    extras = _extra_files(extra_resources)
    reserved = {CONFIG_NAME, "mbdfmu_boot.py", model_module + ".py"}
    clash = sorted(n for n in extras if n in reserved or n.split("/")[0] == runtime_package)
    if clash:
        raise PackageError(f"extra resources use names reserved for the runtime: {', '.join(clash)}")
    variables_json = [v.to_dict() for v in table.variables]
    experiment = asdict(default_experiment) if default_experiment else {}
    guid = "{%s}" % uuid.UUID(_digest(
        model_identifier.encode(), model_class.encode(), json.dumps(variables_json).encode(),
        model_module_source.encode(), runtime_package.encode(), binary_bytes,
        json.dumps([sorted(extras), experiment, asdict(capabilities), log_categories,
                    asdict(info) if info else description]).encode(),
        *extras.values())[:32])
    config = {"format": CONFIG_FORMAT, "model_identifier": model_identifier, "guid": guid,
              "python_library": python.library, "python_home": python.home,
              "python_version": python.version,
              "site_dirs": list(python.site_dirs), "runtime_package": runtime_package,
              "model_module": model_module, "model_class": model_class,
              "variables": variables_json, "log_categories": dict(log_categories or {}),
              "default_experiment": experiment}
    info = info or ModelInfo(description=description)
    xml = model_description(table, model_name or model_identifier, model_identifier, guid,
                            info=info, capabilities=capabilities,
                            default_experiment=default_experiment, log_categories=log_categories)
    members = {"modelDescription.xml": xml.encode("utf-8"),
               f"binaries/linux64/{model_identifier}.so": binary_bytes,
               f"resources/{CONFIG_NAME}": json.dumps(config, indent=1, ensure_ascii=False).encode(),
               "resources/mbdfmu_boot.py": (RUNTIME_DIR / BOOT_FILE).read_bytes(),
               f"resources/{model_module}.py": model_module_source.encode("utf-8")}
    members.update({f"resources/{runtime_package}/{k}": v for k, v in runtime.items()})
    members.update({f"resources/{k}": v for k, v in extras.items()})
    output = Path(output)
    _zip(output, members)
    return output
