"""Bootstrap run by the C wrapper at each fmi2Instantiate (shipped as resources/mbdfmu_boot.py).

The wrapper executes this file with ``runpy.run_path`` (it is never imported, so it has no
module name to clash with) and calls ``boot``. It prepares ``sys.path``, imports the FMU's
runtime package and asks it for a slave. It returns ``(slave, "")`` or
``(None, one line saying what is missing and how to fix it)``; it never raises.

``sys.path`` is changed only as follows:

* ``MBDFMU_PYTHONPATH`` (folders separated by ``os.pathsep``) goes first, in any host;
* the site folders recorded at build time (``site_dirs`` in ``mbdfmu.json``: where numpy
  and scipy were installed) are added with ``site.addsitedir`` only when the wrapper
  started the interpreter itself and its version is the recorded one. A Python host
  keeps its own environment.
"""

from __future__ import annotations

import importlib.util
import json
import os
import site
import sys

CONFIG_FILE = "mbdfmu.json"
ENV_PYTHONPATH = "MBDFMU_PYTHONPATH"


def instantiating(config: dict) -> str:
    """The FMI function that instantiates an FMU of this config (for messages)."""
    return "fmi3InstantiateCoSimulation" if config.get("fmi_version") == 3 else "fmi2Instantiate"


def boot(resources_dir: str, instance_name: str, guid: str, logging_on: bool,
         own_interpreter: bool):
    """``(slave, "")`` for the FMU in ``resources_dir``, or ``(None, the reason in one line)``."""
    try:
        with open(os.path.join(resources_dir, CONFIG_FILE), encoding="utf-8") as f:
            config = json.load(f)
    except (OSError, ValueError) as exc:
        return None, f"Instantiate: cannot read the FMU's {CONFIG_FILE}: {exc}"
    try:
        prepare_path(config, own_interpreter)
        runtime = load_runtime(resources_dir, config["runtime_package"])
        slave, message = runtime.instantiate(resources_dir, config, instance_name, guid, logging_on)
        return slave, message or ""
    except ImportError as exc:
        return None, missing_module(exc, config)
    except BaseException as exc:  # noqa: B902 - the host must get a message, not a crash
        return None, f"{instantiating(config)}: {type(exc).__name__}: {exc}"


def prepare_path(config: dict, own_interpreter: bool) -> None:
    """Put ``MBDFMU_PYTHONPATH`` first and, in an interpreter of our own, the site dirs."""
    extra = [p for p in os.environ.get(ENV_PYTHONPATH, "").split(os.pathsep) if p]
    for folder in reversed(extra):
        if folder not in sys.path:
            sys.path.insert(0, folder)
    recorded = tuple(int(x) for x in str(config.get("python_version", "0.0")).split(".")[:2])
    if own_interpreter and recorded == sys.version_info[:2]:
        for folder in config.get("site_dirs", []):
            if os.path.isdir(folder):
                site.addsitedir(folder)


def load_runtime(resources_dir: str, name: str):
    """The runtime package ``name`` from the resources (once per process and name)."""
    return load_module(name, os.path.join(resources_dir, name))


def load_module(full_name: str, path: str):
    """Import the package in folder ``path`` (or the module ``path``.py) as ``full_name``,
    once per process: a module already imported under that name is returned as is."""
    if full_name in sys.modules:
        return sys.modules[full_name]
    if os.path.isdir(path):
        spec = importlib.util.spec_from_file_location(
            full_name, os.path.join(path, "__init__.py"), submodule_search_locations=[path])
    else:
        spec = importlib.util.spec_from_file_location(full_name, path + ".py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[full_name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[full_name]
        raise
    return module


def missing_module(exc: ImportError, config: dict) -> str:
    """One line: which module this Python cannot import and the two ways to fix it."""
    name = exc.name or "a required module"
    version = ".".join(map(str, sys.version_info[:3]))
    if name.split(".")[0] in getattr(sys, "stdlib_module_names", ()):
        return (f"{instantiating(config)}: Python {version} cannot import its standard module '{name}' "
                f"(prefix {sys.prefix}): its standard library was not found; set "
                "MBDFMU_PYTHON_HOME (or PYTHONHOME) to that Python's sys.base_prefix")
    return (f"{instantiating(config)}: the FMU's Python code needs '{name}', which Python {version} "
            f"(prefix {sys.prefix}) cannot import ({exc}); install it into that Python "
            f"(python{sys.version_info[0]}.{sys.version_info[1]} -m pip install {name.split('.')[0]}) "
            f"or set {ENV_PYTHONPATH} to a folder that has it (the FMU was built with Python "
            f"{config.get('python_version', '?')} and numpy)")
