"""Everything that turns a source into an FMU: ``build(path, output)`` takes a scene
(``.toml``, or a shipped scene's name) or a companion source (``.py``)."""

from __future__ import annotations

from pathlib import Path

from .common import BuildError


FMI_VERSIONS = (2, 3)


def build(path, output=None, parameters: dict[str, float] | None = None,
          fmi_version: int = 2, scene_kernel: bool | None = None) -> Path:
    """``mbdfmu build``: a scene or a companion source into an FMI 2.0 (``fmi_version`` 3:
    FMI 3.0) co-simulation FMU; returns the FMU's path. ``parameters``: start values baked
    into a scene's FMU; ``scene_kernel``: ship the C kernel built for the scene as well
    (default: yes, unless ``$MBDFMU_SCENE_KERNEL`` is 0)."""
    if fmi_version not in FMI_VERSIONS:
        raise BuildError(f"FMI version {fmi_version!r}: mbdfmu builds FMI 2.0 and 3.0 FMUs "
                         "(--fmi-version 2 or 3)")
    if Path(path).suffix == ".py":
        if parameters:
            raise BuildError(f"{path}: start values are baked into scene FMUs only")
        from .companion import build_companion
        return build_companion(path, output, fmi_version)
    from .scene_fmu import build_fmu
    return build_fmu(path, output, parameters, fmi_version, scene_kernel)


__all__ = ["BuildError", "FMI_VERSIONS", "build"]
