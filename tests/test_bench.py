"""mbdfmu bench: same errors on every scheduler, the P1 error measured right, the summary's
interpolation, and the command end to end (quick sweep, synchronous scheduler)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import exact_solutions as ref  # tests/exact_solutions.py: independent of mbdfmu
from mbdfmu import METHODS, cli
from mbdfmu import Simulation, load_scene
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
                     "--comm-steps", "0.1", "--scheduler", "synchronous", "--no-progress",
                     "-o", str(out)])
    assert code == 0
    rows = sweep.read_rows(out / "results.csv")
    assert {r["method"] for r in rows} == {"rk4p", "taylor", "dop853p"}
    assert all(r["stability"] in bench_charts.STABILITY_CLASSES for r in rows)
    comm_rows = [r for r in rows if bench_charts.is_comm(r)]
    assert {r["comm_step"] for r in comm_rows} == {0.1}
    assert len(comm_rows) == 1 + 1 + len(cases.COMM_TOLS)   # rk4p, taylor: one step each
    for name in ("summary.md", "work_precision_P1.png", "stability_P1.png", "comm_steps_P1.png"):
        assert (out / name).stat().st_size > 0
    (out / "summary.md").unlink()
    assert cli.main(["bench", "--from-csv", str(out / "results.csv")]) == 0  # charts from CSV only
    assert (out / "summary.md").exists()
    # the two sweeps run apart, merged by --from-csv into one results.csv
    settings_csv = sweep.write_csv([r for r in rows if r not in comm_rows], tmp_path / "a.csv")
    comm_csv = sweep.write_csv(comm_rows, tmp_path / "b.csv")
    merged = tmp_path / "merged"
    assert cli.main(["bench", "--from-csv", str(settings_csv), str(comm_csv), "-o",
                     str(merged)]) == 0
    assert len(sweep.read_rows(merged / "results.csv")) == len(rows)
    text = (merged / "summary.md").read_text()
    assert "## P1 pendulum, t = 10 s" in text and "## Communication steps: P1 pendulum" in text
    assert cli.main(["bench", "P99", "--scheduler", "synchronous", "-o", str(out)]) == 2
    assert 'unknown bench scene "P99"' in capsys.readouterr().err
    assert cli.main(["bench", "P1", "--comm-steps", "1e-3,fast", "-o", str(out)]) == 2
    assert '--comm-steps: "fast" is not a positive step in s' in capsys.readouterr().err


def test_comm_step_sweep_rows_map_and_silent_count(tmp_path):
    """The communication-step sweep through run_bench: its rows, their errors against the
    elliptic solution at every communication point (stepped here, not by the bench), the map
    and the silent-failure count of summary.md."""
    steps = (0.1, 0.02)
    done = sweep.run_bench(["P1"], methods=["rk4p", "dop853p"], scheduler="synchronous",
                           output=tmp_path, quick=True, progress=False, comm_steps=steps,
                           settings_sweep=False)
    rows = done["rows"]
    case = cases.CASES["P1"]
    expected = {("rk4p", "step", case.comm_step, h) for h in steps} | \
        {("dop853p", "rtol", rtol, h) for rtol in cases.COMM_TOLS for h in steps}
    assert {(r["method"], r["kind"], r["setting"], r["comm_step"]) for r in rows} == expected
    scene = load_scene(bundled_scene(case.scene))
    bob = scene.bodies[0]
    silent = 0
    for r in rows:
        assert r["status"] == "ok" and r["t_reached"] == pytest.approx(case.quick_comm_t_end)
        kw = {"step": r["setting"]} if r["kind"] == "step" else {"rtol": r["setting"]}
        sim = Simulation(scene, method=r["method"], **kw)
        n = round(case.quick_comm_t_end / r["comm_step"])
        t = np.arange(1, n + 1) * r["comm_step"]
        pos = []
        for tk in t:
            sim.advance(float(tk))
            pos.append((sim.outputs()["bob.x"], sim.outputs()["bob.y"]))
        exact = ref.simple_pendulum(t, m=bob.mass, J=bob.inertia)
        error = np.max(np.hypot(np.array(pos)[:, 0] - exact["x"], np.array(pos)[:, 1] - exact["y"]))
        assert r["error"] == pytest.approx(error, rel=1e-6, abs=1e-15)
        silent += r["kind"] == "rtol" and error > 100 * r["setting"]
    assert (tmp_path / "comm_steps_P1.png").stat().st_size > 0
    text = done["summary"].read_text()
    assert f"both sweeps): {silent}." in text
    assert "| dop853p rtol 1e-10 | " in text


def test_summary_lists_silently_wrong_runs(tmp_path):
    # issue 12: an adaptive run that claims success with an error above 100 x its rtol
    rows = [_row("a", 1e-6, 1.0, 5e-5), _row("a", 1e-8, 2.0, 2e-6),   # 50 x (fine), 200 x
            _row("b", 1e-6, 1.0, 1.0, "failed")]                       # failed: said so
    silent = bench_charts.silently_wrong(rows)
    assert [(r["method"], r["setting"]) for r in silent] == [("a", 1e-8)]
    text = bench_charts.write_summary(rows, tmp_path / "summary.md").read_text()
    assert "Silently wrong runs (an adaptive method or auto claiming success with an error " \
           "above 100 x rtol, both sweeps): 1." in text
    assert "rtol 1e-08: error 2e-06" in text
    comm = dict(_row("a", 1e-6, 1.0, 3e-4), comm_step=1e-3)              # 300 x, at h = 1 ms
    assert bench_charts.silently_wrong(rows + [comm])[-1] is comm
    text = bench_charts.write_summary(rows + [comm], tmp_path / "summary.md").read_text()
    assert "P1 a rtol 1e-06 at communication step 0.001 s: error 0.0003" in text


def test_cpu_budget_ends_a_run_inside_one_long_point():
    """The budget is checked inside each ``advance`` too: one point that alone needs far more
    CPU than the budget (10 s of the pendulum in rk4p steps of 10 us, a million steps) stops
    with the bench's reason before it is reached, instead of running on to its end."""
    from mbdfmu.bench.runs import simulate_outputs
    scene = load_scene(bundled_scene("pendulum"))
    out, stats, reached, reason = simulate_outputs(scene, np.array([10.0]), "rk4p", "step",
                                                   1e-5, 0.2)
    assert "CPU budget of 0.2 s per run used up" in reason
    assert reached == 0.0 and stats["nsteps"] < 10 ** 6


def test_a_later_csv_replaces_each_part_it_reruns(tmp_path):
    """--from-csv a.csv b.csv: b's rows replace a's for each scene, method and sweep b
    has (the whole part, whatever its settings), and keep the parts b does not rerun."""
    old = [_row("a", 1e-3, 1.0, 1e-3), _row("a", 1e-6, 2.0, 1e-6), _row("b", 1e-3, 1.0, 1e-4),
           dict(_row("a", 1e-6, 3.0, 1e-6), comm_step=0.01)]
    new = [_row("a", 1e-4, 0.5, 1e-5)]
    paths = []
    for name, rows in (("old.csv", old), ("new.csv", new)):
        paths.append(sweep.write_csv([{"comm_step": "", **r} for r in rows], tmp_path / name))
    merged = sweep.redraw(paths, tmp_path / "out")["rows"]
    kept = sorted((r["method"], r["setting"], math.isnan(r["comm_step"])) for r in merged)
    assert kept == [("a", 1e-6, False), ("a", 1e-4, True), ("b", 1e-3, True)]
