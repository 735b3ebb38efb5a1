"""The work-precision and stability benchmark of every method (``mbdfmu bench``).

Not shipped in FMUs. ``cases``: the benchmark problems and their error functions;
``closed_forms``: exact references (P1, P2, P4, P6); ``sweep``: the runs on Dask and
results.csv; ``charts``: charts and summary.md drawn from that CSV.
"""
