"""Where the time of a run goes: a pyinstrument profile of ``Simulation.advance`` + outputs.

Runs a scene (a bundled name or a .toml path) for ``--t-end`` seconds in communication
steps of ``--step``, reading every output after each step as an FMU master does, and prints
pyinstrument's call tree (time per function, children nested). docs/performance.md quotes
these trees before and after the kernel work.

    python benchmarks/profile_step.py [scene] [--kernel numpy|numba] [--method auto]
                                      [--step 1e-3] [--t-end 0.2]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from pathlib import Path  # noqa: E402

import mbdfmu  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="slider_crank")
    parser.add_argument("--kernel", choices=("numpy", "numba"), default=None)
    parser.add_argument("--method", default=None)
    parser.add_argument("--step", type=float, default=1e-3)
    parser.add_argument("--t-end", type=float, default=0.2)
    args = parser.parse_args(argv)
    try:
        from pyinstrument import Profiler
    except ImportError:
        raise SystemExit('profile_step.py needs pyinstrument: pip install "mbdfmu[bench]"')
    path = Path(args.scene)
    if not path.suffix:
        path = ROOT / "scenes" / f"{args.scene}.toml"
    scene = mbdfmu.load_scene(path)
    # kernel only when given, so that the script also profiles versions before kernels
    options = {"kernel": args.kernel} if args.kernel else {}
    sim = mbdfmu.Simulation(scene, method=args.method, **options)
    sim.advance(args.step)                       # warm-up: numba compilation, caches
    n = int(round(args.t_end / args.step))
    profiler = Profiler(interval=0.0005)
    profiler.start()
    for k in range(2, n + 2):
        sim.advance(k * args.step)
        sim.output_vector()
    profiler.stop()
    print(f"{path.name}: {n} steps of {args.step:g} s, method {sim.method_name}, "
          f"kernel {sim.equations.kernel}")
    print(profiler.output_text(unicode=False, color=False, show_all=False))


if __name__ == "__main__":
    main()
