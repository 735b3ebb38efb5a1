"""Everything that turns a source into an FMU: ``build(path, output)`` takes a scene
(``.toml``, or a shipped scene's name) or a companion source (``.py``)."""

from __future__ import annotations

from pathlib import Path

from .common import BuildError


def build(path, output=None, parameters: dict[str, float] | None = None) -> Path:
    """``mbdfmu build``: a scene or a companion source into an FMI 2.0 co-simulation FMU;
    returns the FMU's path. ``parameters``: start values baked into a scene's FMU."""
    if Path(path).suffix == ".py":
        if parameters:
            raise BuildError(f"{path}: start values are baked into scene FMUs only")
        from .companion import build_companion
        return build_companion(path, output)
    from .scene_fmu import build_fmu
    return build_fmu(path, output, parameters)


__all__ = ["BuildError", "build"]
