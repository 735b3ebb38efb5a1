"""The Python runtime shipped inside every mbdfmu FMU (standard library and numpy only).

In an FMU this folder is ``resources/<runtime package>/``, imported under a name made of
its content hash, so FMUs built with different runtime versions never share one module
in a process, and identical runtimes are loaded once. The model module is loaded as a
submodule of it and imports the base with ``from . import Slave, Discard``.

Entry point for the C wrapper (through ``resources/mbdfmu_boot.py``):
``instantiate(resources_dir, config, instance_name, guid, logging_on) -> (slave, message)``.
"""

from __future__ import annotations

from pathlib import Path

from .boot import load_module
from .slave import Slave
from .status import DISCARD, ERROR, FATAL, OK, PENDING, WARNING, Discard, FmiError
from .variables import Variable, VariableTable
from . import companion  # noqa: E402 - every submodule now: hosts may delete the extracted files

__all__ = ["Slave", "Discard", "FmiError", "Variable", "VariableTable", "instantiate",
           "load_package", "OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING"]


def load_package(resources_dir: str, name: str, parent: str | None = None):
    """Import the module or package ``name`` shipped in ``resources_dir``, once per process.

    ``name`` must be unique to its content (a hash in it): a module already imported under
    that name is returned as is, even if it came from another FMU's resources, which is
    why the name must change whenever the content does. ``parent`` loads it as
    ``parent.name`` (so it can use relative imports from the parent package).
    """
    full = f"{parent}.{name}" if parent else name
    return load_module(full, str(Path(resources_dir) / name))


def instantiate(resources_dir: str, config: dict, instance_name: str, guid: str,
                logging_on: bool):
    """A new slave of the FMU described by ``config``, or (None, the reason)."""
    if guid != config["guid"]:
        function, what = (("fmi3InstantiateCoSimulation", "instantiation token")
                          if config.get("fmi_version") == 3 else ("fmi2Instantiate", "GUID"))
        return None, (f"{function}: {what} {guid!r} is not this FMU's {config['guid']!r} "
                      "(the model description and the resources come from different builds)")
    module = load_package(resources_dir, config["model_module"], parent=__name__)
    cls = getattr(module, config.get("model_class", "Model"), None)
    if not (isinstance(cls, type) and issubclass(cls, Slave)):
        return None, (f"fmi2Instantiate: the model module defines no Slave subclass named "
                      f"{config.get('model_class', 'Model')!r}")
    table = VariableTable([Variable.from_dict(d) for d in config["variables"]])
    start = float(config.get("default_experiment", {}).get("start_time", 0.0))
    slave = cls(instance_name, guid, resources_dir, table, config.get("log_categories", {}),
                bool(logging_on), start, fmi_version=int(config.get("fmi_version", 2)))
    return slave, None
