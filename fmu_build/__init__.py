"""What turns a scene into an FMI 2.0 co-simulation FMU: the slave template and the build step."""

from .build import BuildError, build_fmu

__all__ = ["BuildError", "build_fmu"]
