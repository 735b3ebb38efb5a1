"""Assemble an FMI 2.0 or 3.0 co-simulation FMU around the native wrapper: ``write_fmu``.

The .fmu (a zip) holds::

    modelDescription.xml                 from the variable table (model_description.py)
    binaries/linux64/<id>.so             the compiled fmi2.c (fmi3.c), the same for every
                                         FMU of that FMI version
    (binaries/x86_64-linux/<id>.so       FMI 3.0's name of the platform folder)
    resources/mbdfmu.json                what the wrapper and the runtime read (below)
    resources/mbdfmu_boot.py             run by the wrapper at fmi2Instantiate
    resources/mbdfmu_fmi2_<hash>/        the runtime package (fmu_build/runtime)
    resources/model_<hash>.py            the model module (a Slave subclass)
    resources/...                        extra resources of the model
    extra/...                            tool data (the OSP power ports, osp.py)

``mbdfmu.json``: ``format``, ``fmi_version``, ``model_identifier``, ``guid`` (FMI 3.0's
instantiation token), ``python_library`` (the
libpython to load in a host without Python), ``python_home`` (its ``sys.base_prefix``,
where its standard library is), ``python_version``, ``site_dirs`` (where the
build's numpy and scipy live), ``runtime_package``, ``model_module``, ``model_class``,
``variables``, ``log_categories``, ``default_experiment``.

Module names carry a hash of their content: several FMUs share one interpreter in a
process, and a module is imported once per name.

An FMI 3.0 FMU's variable table is the FMI 2.0 one (same value references) with FMI 3.0's
independent variable ``time`` and, for a model that follows input polynomials, the
derivative inputs ``der(u)`` and ``der(u,2)`` of each Real input appended
(``fmi3_variables``; runtime/fmi3.py).
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
from xml.etree import ElementTree as ET

from .model_description import (Capabilities, DefaultExperiment, ModelInfo, model_description,
                                unit_exponents)
from .native import compile_wrapper
from .runtime.variables import Variable, VariableTable

RUNTIME_DIR = Path(__file__).with_name("runtime")
BOOT_FILE = "boot.py"
CONFIG_NAME = "mbdfmu.json"
CONFIG_FORMAT = 1
# Fixed zip timestamp: the same inputs give the same .fmu bytes.
ZIP_TIME = (1980, 1, 1, 0, 0, 0)
IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# The binaries' folder (FMI 2.0 and 3.0 name the Linux x86-64 platform differently).
PLATFORMS = {2: "linux64", 3: "x86_64-linux"}


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


def per_second(unit: str | None, k: int) -> str | None:
    """The unit of a k-th time derivative (``m/s`` -> ``m/s2``, ``N.m`` -> ``N.m/s``), or
    None when ``unit`` is none or not of the form ``num/den``."""
    if not unit:
        return None
    numerator, _, denominator = unit.partition("/")
    inner = denominator[1:-1] if denominator.startswith("(") else denominator
    tokens = [t for t in inner.split(".") if t]
    for i, token in enumerate(tokens):
        match = re.fullmatch(r"s(\d*)", token)
        if match:
            tokens[i] = f"s{int(match.group(1) or 1) + k}"
            break
    else:
        tokens.insert(0, f"s{k}" if k > 1 else "s")
    body = ".".join(tokens)
    result = f"{numerator}/({body})" if len(tokens) > 1 else f"{numerator}/{body}"
    try:
        unit_exponents(result)
    except ValueError:
        return None
    return result


def fmi3_variables(variables, interpolates_inputs: bool) -> list[Variable]:
    """The FMI 3.0 table of an FMU (module docstring): ``variables``, then ``time``, then
    ``der(u)`` and ``der(u,2)`` of each Real input when ``interpolates_inputs``."""
    variables = list(variables)
    vr = max((v.value_reference for v in variables), default=-1) + 1
    extra = [Variable("time", vr, causality="independent", unit="s",
                      description="simulation time")]
    for v in variables if interpolates_inputs else ():
        if v.causality == "input" and v.type == "Real" and v.derivative is None:
            first, second = f"der({v.name})", f"der({v.name},2)"
            extra += [Variable(first, vr + len(extra), causality="input", start=0.0,
                               unit=per_second(v.unit, 1), derivative=v.name,
                               description=f"time derivative of {v.name} (held over a step)"),
                      Variable(second, vr + len(extra) + 1, causality="input", start=0.0,
                               unit=per_second(v.unit, 2), derivative=first,
                               description=f"second time derivative of {v.name}")]
    return variables + extra


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


def _python_config(python: PythonEnvironment) -> dict:
    return {"python_library": python.library, "python_home": python.home,
            "python_version": python.version, "site_dirs": list(python.site_dirs)}


def _module_names(runtime: dict[str, bytes], model_module_source: str,
                  extras: dict[str, bytes]) -> tuple[str, str]:
    """The runtime package's and the model module's names (content hashes); extra resources
    may not take them."""
    runtime_package = "mbdfmu_fmi2_" + _digest(*(k.encode() + v for k, v in runtime.items()))[:16]
    model_module = "model_" + _digest(model_module_source.encode())[:16]
    reserved = {CONFIG_NAME, "mbdfmu_boot.py", model_module + ".py"}
    clash = sorted(n for n in extras if n in reserved or n.split("/")[0] == runtime_package)
    if clash:
        raise PackageError(f"extra resources use names reserved for the runtime: {', '.join(clash)}")
    return runtime_package, model_module


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
              info: ModelInfo | None = None, extra_resources=None,
              capabilities: Capabilities = Capabilities(),
              default_experiment: DefaultExperiment | None = DefaultExperiment(),
              log_categories: dict[str, str] | None = None,
              python: PythonEnvironment | None = None, binary=None, cache_dir=None,
              fmi_version: int = 2, annotations=None, extra_files=None) -> Path:
    """Write an FMI 2.0 (``fmi_version`` 3: 3.0) co-simulation FMU to ``output`` and return
    its path.

    ``variables``: ``Variable`` objects (the one table of value references); ``info``:
    author, version, generation tool (and the description, overriding ``description``);
    ``model_module_source``: Python source defining ``model_class``, a subclass of the
    runtime's ``Slave`` imported with ``from . import Slave``; ``extra_resources``: name
    under resources/ -> bytes, text, or the path of a file or folder; ``log_categories``:
    the model's own categories (name -> description); ``python``: the environment recorded
    for hosts without Python (default: this interpreter); ``binary``: a compiled wrapper
    (default: ``compile_wrapper(cache_dir, fmi_version)``); ``annotations``: tool name ->
    XML element (model_description); ``extra_files``: name under extra/ -> bytes. The GUID
    digests everything shipped (same inputs, same FMU; a build's states load into it only)."""
    if fmi_version == 3:
        variables = fmi3_variables(variables, capabilities.can_interpolate_inputs)
    table = _check_inputs(model_identifier, variables, model_module_source)
    python = python or PythonEnvironment.current()
    binary_bytes = Path(binary or compile_wrapper(cache_dir, fmi_version)).read_bytes()
    runtime = runtime_files()
    extras = _extra_files(extra_resources)
    runtime_package, model_module = _module_names(runtime, model_module_source, extras)
    variables_json = [v.to_dict() for v in table.variables]
    experiment = asdict(default_experiment) if default_experiment else {}
    marked = {k: ET.tostring(e, encoding="unicode") for k, e in (annotations or {}).items()}
    guid = "{%s}" % uuid.UUID(_digest(
        model_identifier.encode(), model_class.encode(), json.dumps(variables_json).encode(),
        model_module_source.encode(), runtime_package.encode(), binary_bytes,
        json.dumps([sorted(extras), experiment, asdict(capabilities), log_categories,
                    asdict(info) if info else description, fmi_version, marked]).encode(),
        *extras.values(), *(k.encode() + v for k, v in sorted((extra_files or {}).items())))[:32])
    config = {"format": CONFIG_FORMAT, "fmi_version": fmi_version,
              "model_identifier": model_identifier, "guid": guid, **_python_config(python),
              "runtime_package": runtime_package, "model_module": model_module,
              "model_class": model_class, "variables": variables_json,
              "log_categories": dict(log_categories or {}), "default_experiment": experiment}
    info = info or ModelInfo(description=description)
    xml = model_description(table, model_name or model_identifier, model_identifier, guid,
                            info=info, capabilities=capabilities,
                            default_experiment=default_experiment, log_categories=log_categories,
                            fmi_version=fmi_version, annotations=annotations)
    platform = PLATFORMS[fmi_version]
    members = {"modelDescription.xml": xml.encode("utf-8"),
               f"binaries/{platform}/{model_identifier}.so": binary_bytes,
               f"resources/{CONFIG_NAME}": json.dumps(config, indent=1, ensure_ascii=False).encode(),
               "resources/mbdfmu_boot.py": (RUNTIME_DIR / BOOT_FILE).read_bytes(),
               f"resources/{model_module}.py": model_module_source.encode("utf-8")}
    members.update({f"resources/{runtime_package}/{k}": v for k, v in runtime.items()})
    members.update({f"resources/{k}": v for k, v in extras.items()}
                   | {f"extra/{k}": v for k, v in (extra_files or {}).items()})
    output = Path(output)
    _zip(output, members)
    return output
