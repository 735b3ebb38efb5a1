"""Co-simulation: scenarios of mbdfmu FMUs coupled with companion FMUs, and the masters
that run them (building FMUs is ``fmu_build``'s job).

Layer: above the simulation and the FMU build, below the CLI.

* ``scenario``, ``scenario_reader``: the connection description
  (``scenarios/<name>/connections.toml``);
* ``settings``: ``CosimSettings`` (one run) and ``CosimError``;
* ``fmpy_master``, ``variable_step``: Jacobi, Gauss-Seidel and an error-controlled
  variable step on fmpy (``run_fmpy``);
* ``ssp_runner``: the scenario as an SSP file, run with fmpy's SSP runner (``run_ssp``);
* ``libcosim_runner``: the scenario in OSP libcosim (``run_libcosim``);
* ``ecos_runner``: the scenario's SSP in Ecos (``run_ecos``);
* ``cosimulate``: one call for all four, CSV and plots (``mbdfmu cosim``).
"""
