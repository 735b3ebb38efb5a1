"""mbdfmu bench: same errors on every scheduler, the P1 error measured right, the summary's
interpolation, and the command end to end (quick sweep, synchronous scheduler)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import exact_solutions as ref  # tests/exact_solutions.py: independent of mbdfmu
from mbdfmu import METHODS, cli
from mbdfmu import load_scene
from mbdfmu.bench import cases, sweep
from mbdfmu.bench import charts as bench_charts
from mbdfmu.bench import closed_forms as pkg_ref
from mbdfmu.model.reader import bundled_scene

pytest.importorskip("dask.distributed")

COMPARED = ("scene", "method", "kind", "setting", "status", "stability", "error",
            "energy_drift", "constraint_drift", "velocity_drift", "nsteps", "naccel", "reason")


def test_quick_sweep_same_errors_on_local_cluster_and_synchronous():
    case = cases.CASES["P1"]
    refs = {"P1": sweep.reference_for(case, True, None)[0]}
    tasks = sweep.make_tasks(["P1"], list(METHODS), True, refs)
    assert {t["method"] for t in tasks} == set(METHODS)  # every registered method, none hard-coded
    sync = sweep.run_tasks(tasks, "synchronous", progress=False)
    local = sweep.run_tasks(tasks, None, progress=False)
    assert [[r[k] for k in COMPARED] for r in sync] == [[r[k] for k in COMPARED] for r in local]
    ok = [r for r in sync if r["status"] == "ok"]
    assert ok and all(r["error"] >= 0 and r["cpu_s"] > 0 for r in ok)


def test_package_pendulum_reference_matches_the_independent_one():
    t = np.linspace(0.0, 10.0, 401)
    mine = pkg_ref.pendulum(t, J=1e-6)
    theirs = ref.simple_pendulum(t, J=1e-6)
    assert np.max(np.abs(mine["x"] - theirs["x"])) < 1e-13
    assert np.max(np.abs(mine["y"] - theirs["y"])) < 1e-13


def test_pendulum_error_is_the_distance_to_the_elliptic_solution():
    """A tight run of the true pendulum has a tiny error; one with gravity 1e-4 stronger has
    the error the exact solutions predict (the distance between the two elliptic motions)."""
    case = cases.CASES["P1"]
    scene = load_scene(bundled_scene(case.scene))
    t_out = np.linspace(0.0, 2.0, 21)
    out, _, _, reason = sweep.simulate_outputs(scene, t_out, "dop853p", "rtol", 1e-11, math.inf)
    assert not reason
    assert cases.ERRORS["P1"](case, scene, t_out, out, {}) < 1e-9

    eps = 1e-4
    heavier = dataclasses.replace(scene, gravity=(0.0, -ref.G * (1 + eps)))
    out, _, _, reason = sweep.simulate_outputs(heavier, t_out, "dop853p", "rtol", 1e-11, math.inf)
    assert not reason
    bob = scene.bodies[0]
    true = ref.simple_pendulum(t_out, m=bob.mass, J=bob.inertia)
    fast = ref.simple_pendulum(t_out, m=bob.mass, J=bob.inertia, g=ref.G * (1 + eps))
    expected = np.max(np.hypot(fast["x"] - true["x"], fast["y"] - true["y"]))
    assert expected > 1e-4  # a perturbation well above the solver's error
    got = cases.ERRORS["P1"](case, scene, t_out, out, {})
    assert got == pytest.approx(expected, rel=1e-5)


def test_time_to_reach_interpolates_log_log():
    line = [(1.0, 1e-3), (10.0, 1e-7), (100.0, 1e-9)]  # (cpu, error), coarse setting first
    cpu, how = bench_charts.time_to_reach(line, 1e-5)
    assert how == "interpolated" and cpu == pytest.approx(10 ** 0.5)
    cpu, how = bench_charts.time_to_reach(line, 1e-8)
    assert how == "interpolated" and cpu == pytest.approx(10 ** 1.5)
    assert bench_charts.time_to_reach(line, 1e-2) == (1.0, "at most")
    cpu, how = bench_charts.time_to_reach(line, 1e-10)
    assert how == "cannot" and math.isnan(cpu)
    # a line that goes below the level, back up, and below again: the first crossing counts
    cpu, how = bench_charts.time_to_reach([(1.0, 1e-3), (2.0, 1e-5), (4.0, 1e-3), (8.0, 1e-6)], 1e-4)
    assert how == "interpolated" and cpu == pytest.approx(2 ** 0.5)


def _row(method, setting, cpu, error, status="ok"):
    return {"scene": "P1", "method": method, "kind": "rtol", "setting": setting, "cpu_s": cpu,
            "error": error, "status": status, "stability": "stable" if status == "ok" else "failed",
            "reason": "" if status == "ok" else "t = 1 s: diverged"}


def test_summary_on_synthetic_rows(tmp_path):
    rows = [_row("a", 1e-3, 1.0, 1e-3), _row("a", 1e-6, 10.0, 1e-7),
            _row("b", 1e-3, 0.5, 1e-5), _row("b", 1e-6, 0.7, 1e-6), _row("b", 1e-9, 1.0, math.nan, "failed")]
    table = bench_charts.reach_table(rows)
    assert table["b"][0] == (0.5, "at most")
    assert table["b"][2][1] == "cannot"
    assert table["a"][1][0] == pytest.approx(10 ** 0.75)
    assert bench_charts.fastest(table) == ["b", "b", "none"]
    text = bench_charts.write_summary(rows, tmp_path / "summary.md").read_text()
    assert "| **fastest** | **b** | **b** | **none** |" in text and "diverged" in text


def test_bench_command_quick_synchronous(tmp_path, capsys):
    out = tmp_path / "bench"
    code = cli.main(["bench", "P1", "--quick", "--methods", "rk4p", "taylor", "dop853p",
                     "--scheduler", "synchronous", "--no-progress", "-o", str(out)])
    assert code == 0
    rows = sweep.read_rows(out / "results.csv")
    assert {r["method"] for r in rows} == {"rk4p", "taylor", "dop853p"}
    assert all(r["stability"] in bench_charts.STABILITY_CLASSES for r in rows)
    for name in ("summary.md", "work_precision_P1.png", "stability_P1.png"):
        assert (out / name).stat().st_size > 0
    (out / "summary.md").unlink()
    assert cli.main(["bench", "--from-csv", str(out / "results.csv")]) == 0  # charts from CSV only
    assert (out / "summary.md").exists()
    assert cli.main(["bench", "P99", "--scheduler", "synchronous", "-o", str(out)]) == 2
    assert 'unknown bench scene "P99"' in capsys.readouterr().err


def test_summary_lists_silently_wrong_runs(tmp_path):
    # issue 12: an adaptive run that claims success with an error above 100 x its rtol
    rows = [_row("a", 1e-6, 1.0, 5e-5), _row("a", 1e-8, 2.0, 2e-6),   # 50 x (fine), 200 x
            _row("b", 1e-6, 1.0, 1.0, "failed")]                       # failed: said so
    silent = bench_charts.silently_wrong(rows)
    assert [(r["method"], r["setting"]) for r in silent] == [("a", 1e-8)]
    text = bench_charts.write_summary(rows, tmp_path / "summary.md").read_text()
    assert "Silently wrong runs (an adaptive method claiming success with an error above " \
           "100 x rtol): 1." in text
    assert "rtol 1e-08: error 2e-06" in text
