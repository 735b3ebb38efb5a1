"""Co-simulation: scenarios of mbdfmu FMUs coupled with companion FMUs, and their masters.

Layer: above the simulation and the FMU build, below the CLI.

* ``scenario``: the connection description (``scenarios/<name>/connections.toml``);
* ``companion``, ``companion_base``: companion FMUs (DC motor, hydraulics, ...) from Python
  sources, and ``build``, the one entry point of ``mbdfmu build``;
* ``master``: Jacobi, Gauss-Seidel and an error-controlled variable step on fmpy;
* ``ssp``: the scenario as an SSP file, run with fmpy's SSP runner;
* ``libcosim``: the scenario in OSP libcosim (libcosimpy);
* ``run``: one call for all three, CSV and plots (``mbdfmu cosim``).
"""
