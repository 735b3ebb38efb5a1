"""Charts and summary of ``mbdfmu bench``, drawn from the rows of results.csv only.

- ``work_precision``: error against CPU time, log-log, one line per method (failed runs
  are left out of the line and counted in the legend);
- ``stability_map``: method by setting (step size for fixed-step methods, rtol for
  adaptive ones), each cell stable / drifting / unstable / failed (reasons in the CSV);
- ``comm_map``: the communication-step sweep (rows with a ``comm_step``), method and
  setting by communication step, each cell its error or, for a failed run, a short reason;
- ``write_summary``: per scene, the CPU time each method needs to reach each error level
  of ``cases.LEVELS``, interpolated on its work-precision line (``time_to_reach``); the
  communication-step sweep's errors; the silently wrong runs of both sweeps (adaptive and
  fixed-step methods counted apart).
"""

from __future__ import annotations

import math
from pathlib import Path

from ..integrators.settings import FIXED_STEP_RTOL
from ..plotting import figure
from .cases import CASES, LEVELS

STABILITY_CLASSES = ("stable", "drifting", "unstable", "failed")
STABILITY_COLORS = ("#4daf4a", "#ffd92f", "#ff7f00", "#b2182b")
DPI = 110
# A run claiming success with an error above this times its rtol is silently wrong (issue 12).
SILENT_FACTOR = 100.0


def is_comm(row) -> bool:
    """A row of the communication-step sweep (CSVs from before it have no such column)."""
    return math.isfinite(_float(row.get("comm_step", "")))


def _by_scene(rows, comm=False):
    """{scene: rows} of the settings sweep, or of the communication-step sweep."""
    scenes: dict[str, list[dict]] = {}
    for r in rows:
        if is_comm(r) == comm:
            scenes.setdefault(r["scene"], []).append(r)
    return scenes


def _methods(rows):
    seen = []
    for r in rows:
        if r["method"] not in seen:
            seen.append(r["method"])
    return seen


def _line(rows, method):
    """(cpu, error, setting) of a method's successful runs, coarse setting first."""
    pts = [(r["cpu_s"], r["error"], r["setting"]) for r in rows
           if r["method"] == method and r["status"] == "ok" and math.isfinite(r["error"])
           and r["error"] > 0]
    return sorted(pts, key=lambda p: -p[2])


def time_to_reach(points, level):
    """CPU time at which a work-precision line first reaches ``error <= level``.

    ``points``: (cpu, error) of one method, in the order of its line (coarse setting first).
    Walks the line and interpolates log(cpu) linearly in log(error) on the first segment
    that crosses ``level``. Returns (cpu, how): how is "interpolated", "at most" (the first,
    coarsest point is already below the level: its time is an upper bound) or "cannot"
    (no point reaches it; cpu is nan).
    """
    for i, (cpu, err) in enumerate(points):
        if err <= level:
            if i == 0:
                return cpu, "at most"
            c0, e0 = points[i - 1]
            if e0 == err:
                return cpu, "interpolated"
            frac = (math.log(level) - math.log(e0)) / (math.log(err) - math.log(e0))
            return math.exp(math.log(c0) + frac * (math.log(cpu) - math.log(c0))), "interpolated"
    return math.nan, "cannot"


def work_precision(rows, key, path):
    fig = figure(figsize=(7, 5))
    ax = fig.subplots()
    for m in _methods(rows):
        pts = _line(rows, m)
        failed = sum(1 for r in rows if r["method"] == m and r["status"] != "ok")
        kind = next((r["kind"] for r in rows if r["method"] == m), "")
        label = f"{m} ({'h' if kind == 'step' else 'rtol'} sweep" + \
            (f", {failed} failed)" if failed else ")")
        if pts:
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", ms=4, label=label)
        else:
            ax.plot([], [], "x", label=label + " no successful run")
    for level in LEVELS:
        ax.axhline(level, color="0.8", lw=0.8, zorder=0)
    ax.set_xlabel("CPU time per run (s)")
    ax.set_ylabel("error against the reference")
    case = CASES.get(key)
    ax.set_title(f"Work-precision: {case.title if case else key}", fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    return path


def _grid(rows, kind):
    methods = [m for m in _methods(rows) if any(r["method"] == m and r["kind"] == kind
                                                 for r in rows)]
    settings = sorted({r["setting"] for r in rows if r["kind"] == kind}, reverse=True)
    cells = [[None] * len(settings) for _ in methods]
    for r in rows:
        if r["kind"] == kind:
            cells[methods.index(r["method"])][settings.index(r["setting"])] = r
    return methods, settings, cells


def stability_map(rows, key, path):
    panels = [k for k in ("step", "rtol") if any(r["kind"] == k for r in rows)]
    widths = [max(3, len({r["setting"] for r in rows if r["kind"] == k})) for k in panels]
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Rectangle

    fig = figure(figsize=(2.2 + 0.75 * sum(widths), 3.6))
    axes = fig.subplots(1, len(panels), gridspec_kw={"width_ratios": widths}, squeeze=False)
    cmap = ListedColormap(STABILITY_COLORS)
    for ax, kind in zip(axes[0], panels):
        methods, settings, cells = _grid(rows, kind)
        codes = [[STABILITY_CLASSES.index(c["stability"]) if c else math.nan for c in line]
                 for line in cells]
        ax.imshow(codes, cmap=cmap, vmin=-0.5, vmax=3.5, aspect="auto")
        for i, line in enumerate(cells):
            for j, c in enumerate(line):
                if c is None:
                    continue
                text = {"failed": "fail", "unstable": "unst", "drifting": "drift"}.get(
                    c["stability"], f"{c['error']:.0e}")
                ax.text(j, i, text, ha="center", va="center", fontsize=6.5)
        ax.set_xticks(range(len(settings)), [f"{s:g}" for s in settings], rotation=45, fontsize=7)
        ax.set_yticks(range(len(methods)), methods, fontsize=8)
        ax.set_xlabel("fixed step h (s)" if kind == "step" else "rtol (adaptive)", fontsize=8)
    case = CASES.get(key)
    handles = [Rectangle((0, 0), 1, 1, color=c) for c in STABILITY_COLORS]
    fig.legend(handles, STABILITY_CLASSES, loc="upper right", ncol=4, fontsize=7)
    fig.suptitle(f"Stability: {case.title if case else key}", fontsize=10, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    fig.savefig(path, dpi=DPI)
    return path


# Failure reasons, shortened for the communication-step maps: (words in the reason, label).
SHORT_REASONS = (("CPU budget", "budget"), ("energy balance", "energy"),
                 ("step size fell", "h -> 0"), ("Newton", "Newton"), ("projection", "project"),
                 ("diverged", "diverged"), ("stated accuracy", "accuracy"),
                 ("unexpected", "bug"))


def short_reason(reason: str) -> str:
    return next((label for words, label in SHORT_REASONS if words in reason), "failed")


def _comm_grid(rows):
    """(labels, steps, cells) of one scene's communication-step rows: a line per method and
    setting, a column per communication step (smallest first)."""
    labels = []
    for r in rows:
        label = _comm_label(r)
        if label not in labels:
            labels.append(label)
    steps = sorted({_float(r["comm_step"]) for r in rows})
    cells = [[None] * len(steps) for _ in labels]
    for r in rows:
        cells[labels.index(_comm_label(r))][steps.index(_float(r["comm_step"]))] = r
    return labels, steps, cells


def _comm_label(r) -> str:
    return f"{r['method']} {'h' if r['kind'] == 'step' else 'rtol'} {_float(r['setting']):g}"


def _comm_cell(r) -> str:
    if r["status"] != "ok":
        return f"{short_reason(r['reason'])}\nt={_float(r['t_reached']):.3g}"
    return f"{_float(r['error']):.0e}"


def comm_map(rows, key, path):
    """The communication-step sweep of one scene: a cell per method, setting and step,
    coloured by stability class, with its error or why it stopped (and when, s)."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Rectangle

    labels, steps, cells = _comm_grid(rows)
    fig = figure(figsize=(3.0 + 1.0 * len(steps), 1.2 + 0.32 * len(labels)))
    ax = fig.subplots()
    codes = [[STABILITY_CLASSES.index(c["stability"]) if c else math.nan for c in line]
             for line in cells]
    ax.imshow(codes, cmap=ListedColormap(STABILITY_COLORS), vmin=-0.5, vmax=3.5, aspect="auto")
    for i, line in enumerate(cells):
        for j, c in enumerate(line):
            if c is not None:
                ax.text(j, i, _comm_cell(c), ha="center", va="center", fontsize=6.5)
    ax.set_xticks(range(len(steps)), [f"{h:g}" for h in steps], fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=7.5)
    ax.set_xlabel("communication step (s): one Simulation.advance call each", fontsize=8)
    case = CASES.get(key)
    t_end = _float(max(r["t_reached"] for r in rows if r["status"] == "ok")) \
        if any(r["status"] == "ok" for r in rows) else math.nan
    handles = [Rectangle((0, 0), 1, 1, color=c) for c in STABILITY_COLORS]
    fig.legend(handles, STABILITY_CLASSES, loc="upper right", ncol=4, fontsize=7)
    fig.suptitle(f"Communication steps: {case.title.split(', t =')[0] if case else key}, "
                 f"t = {t_end:g} s", fontsize=10, x=0.02, ha="left")
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=DPI)
    return path


def comm_summary(rows) -> list[str]:
    """summary.md's lines on the communication-step sweep: per scene, a table of errors
    (or the short reason and the time a run stopped)."""
    lines = []
    for key, srows in _by_scene(rows, comm=True).items():
        labels, steps, cells = _comm_grid(srows)
        case = CASES.get(key)
        lines += [f"## Communication steps: {case.title.split(', t =')[0] if case else key}", "",
                  "Error at the recorded communication points, or why and when (s) the run "
                  "stopped; CPU time in brackets.", "",
                  "| method, setting | " + " | ".join(f"h = {h:g} s" for h in steps) + " |",
                  "|---|" + "---|" * len(steps)]
        for label, line in zip(labels, cells):
            lines.append(f"| {label} | " + " | ".join(
                "" if c is None else _comm_cell(c).replace("\n", " ") +
                f" ({_float(c['cpu_s']):.2g} s)" for c in line) + " |")
        lines += ["", f"![communication steps](comm_steps_{key}.png)", ""]
    return lines


def draw_all(rows, out: Path) -> list[Path]:
    out = Path(out)
    paths = []
    for key, srows in _by_scene(rows).items():
        paths.append(work_precision(srows, key, out / f"work_precision_{key}.png"))
        paths.append(stability_map(srows, key, out / f"stability_{key}.png"))
    for key, srows in _by_scene(rows, comm=True).items():
        paths.append(comm_map(srows, key, out / f"comm_steps_{key}.png"))
    return paths


def reach_table(rows) -> dict:
    """{method: [(cpu, how) per level]} for one scene's rows."""
    return {m: [time_to_reach([(c, e) for c, e, _ in _line(rows, m)], lv) for lv in LEVELS]
            for m in _methods(rows)}


def fastest(table) -> list[str]:
    """Per level, the method with the smallest CPU time (or "none")."""
    best = []
    for k in range(len(LEVELS)):
        cands = [(v[k][0], m) for m, v in table.items() if v[k][1] != "cannot"]
        best.append(min(cands)[1] if cands else "none")
    return best


def _fmt(cpu, how):
    if how == "cannot":
        return "cannot"
    return f"<= {cpu:.3g} s" if how == "at most" else f"{cpu:.3g} s"


def silently_wrong(rows, fixed_step: bool = False) -> list:
    """Runs of an adaptive method or ``auto`` (kind "rtol", the setting its rtol), in either
    sweep, that claim success with an error above SILENT_FACTOR times that rtol (errors in
    the scenes' units, m or rad of metre-sized mechanisms): issue 12's count, whose target
    is none. ``fixed_step``: the same for fixed-step methods (kind "step"), against the
    rtol they state when given none, FIXED_STEP_RTOL (the bench gives none)."""
    kind = "step" if fixed_step else "rtol"
    return [r for r in rows if r["kind"] == kind and r["status"] == "ok"
            and math.isfinite(_float(r["error"]))
            and _float(r["error"]) > SILENT_FACTOR * (FIXED_STEP_RTOL if fixed_step
                                                      else _float(r["setting"]))]


def _silent_lines(rows) -> list[str]:
    """summary.md's count and list of silently wrong runs: adaptive ones, then fixed-step."""
    lines = []
    for fixed, what in ((False, "an adaptive method or auto claiming success with an error "
                                f"above {SILENT_FACTOR:g} x rtol"),
                        (True, "a fixed-step method claiming success with an error above "
                               f"{SILENT_FACTOR:g} x its stated rtol {FIXED_STEP_RTOL:g}")):
        silent = silently_wrong(rows, fixed_step=fixed)
        lines.append(f"Silently wrong {'fixed-step ' if fixed else ''}runs ({what}, both "
                     f"sweeps): {len(silent)}.")
        lines += [f"- {r['scene']} {r['method']} {'h' if fixed else 'rtol'} "
                  f"{_float(r['setting']):g}" +
                  (f" at communication step {_float(r['comm_step']):g} s" if is_comm(r) else "")
                  + f": error {_float(r['error']):.2g}" for r in silent]
    return lines


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def write_summary(rows, path: Path, notes: dict | None = None, footer: str = "") -> Path:
    notes = notes or {}
    lines = ["# mbdfmu bench summary", "",
             "CPU time each method needs to reach an error of 1e-4, 1e-6 and 1e-8 against the "
             "scene's reference, interpolated (log-log) on its work-precision line; "
             "\"<=\" when its coarsest setting is already below the level; \"cannot\" when "
             "no setting of the sweep reaches it.", ""] + _silent_lines(rows)
    lines.append("")
    for key, srows in _by_scene(rows).items():
        case = CASES.get(key)
        table = reach_table(srows)
        lines += [f"## {case.title if case else key}", "",
                  f"Reference: {notes.get(key, case.reference if case else '?')}.", "",
                  "| method | " + " | ".join(f"{lv:.0e}" for lv in LEVELS) +
                  " | best error | failed runs |",
                  "|---|" + "---|" * (len(LEVELS) + 2)]
        for m, vals in table.items():
            errs = [r["error"] for r in srows if r["method"] == m and r["status"] == "ok"
                    and math.isfinite(r["error"])]
            nfail = sum(1 for r in srows if r["method"] == m and r["status"] != "ok")
            ntot = sum(1 for r in srows if r["method"] == m)
            lines.append(f"| {m} | " + " | ".join(_fmt(*v) for v in vals) +
                         f" | {min(errs):.2g} | {nfail}/{ntot} |" if errs else
                         f"| {m} | " + " | ".join(_fmt(*v) for v in vals) + f" | - | {nfail}/{ntot} |")
        lines.append("| **fastest** | " + " | ".join(f"**{b}**" for b in fastest(table)) + " | | |")
        reasons = sorted({(r["method"], r["reason"].split(": ", 1)[-1][:110]) for r in srows
                          if r["status"] != "ok"})
        if reasons:
            lines += ["", "Failures (first reason per method and kind; every one is in results.csv):"]
            seen = set()
            for m, reason in reasons:
                if m not in seen:
                    lines.append(f"- {m}: {reason}")
                    seen.add(m)
        lines += ["", f"![work-precision](work_precision_{key}.png) "
                      f"![stability](stability_{key}.png)", ""]
    lines += comm_summary(rows)
    if footer:
        lines += [footer, ""]
    Path(path).write_text("\n".join(lines), encoding="utf-8")
    return Path(path)
