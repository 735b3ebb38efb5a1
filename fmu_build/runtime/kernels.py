"""Which kernel a scene's FMU runs: ``$MBDFMU_KERNEL`` if set, else the C kernels shipped
in its resources (compiled at ``mbdfmu build``: nothing compiles at load), else numpy;
every fallback is logged (docs/performance.md, "The FMU's compiled step")."""

from __future__ import annotations

import os

# The kernel built for the FMU's scene (ckernel/scene_kernel.py), beside the generic one:
# for the equations it starts on, and for its other contact modes' (1, 2, ...).
SCENE_KERNEL_FILE = "mbdfmu_scene_kernel.so"
MODE_KERNEL_FILE = "mbdfmu_scene_kernel_mode{}.so"


def load_kernel(resources, kernel_file: str, ckernel, log) -> tuple[str, bool]:
    """The kernel name for ``Simulation`` ("c" with the shipped libraries in use, else what
    is set or numpy), and whether the kernel built for the scene was offered to every
    Kernel of its structure."""
    if os.environ.get("MBDFMU_KERNEL"):
        return os.environ["MBDFMU_KERNEL"], False
    path = resources / kernel_file
    if not path.is_file():
        log("no compiled C kernel in this FMU (no C compiler at build): the numpy kernel "
            "runs, about 30 times slower")
        return "numpy", False
    try:
        ckernel.use_library(path)
        ckernel.library()
    except OSError as exc:
        log(f"the FMU's C kernel cannot be loaded here ({exc}): the numpy kernel runs")
        return "numpy", False
    scene = resources / SCENE_KERNEL_FILE
    if not scene.is_file():
        return "c", False
    try:
        ckernel.use_scene_library(scene)
    except (OSError, AttributeError) as exc:
        log(f"the FMU's kernel built for its scene cannot be loaded here ({exc}): the "
            "generic C kernel runs")
        return "c", False
    for path in sorted(resources.glob(MODE_KERNEL_FILE.format("*"))):
        try:
            ckernel.use_scene_library(path)
        except (OSError, AttributeError) as exc:
            log(f"the FMU's kernel built for one of its contact modes ({path.name}) cannot "
                f"be loaded here ({exc}): that mode runs the generic C kernel")
    return "c", True


def log_scene_kernel(sim, log) -> None:
    """Say when the kernel built for the FMU's scene, offered, is not taken by the
    equations it steps (their structure is not the one it was built for): the generic
    kernel runs."""
    kernel = getattr(sim.stepped_equations, "ckernel", None)
    if kernel is not None and not kernel.scene_built:
        log("the FMU's kernel built for its scene does not fit its equations: the generic C "
            "kernel runs")
