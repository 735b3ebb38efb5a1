"""The shape of the code, checked against docs/architecture.md: layers import downward
only, no import cycle, modules, classes and functions of a readable size, FMUs free of
benchmark, plotting and CLI code, and the generated docs current."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {"mbdfmu": ROOT / "src" / "mbdfmu", "mbdfmu.fmu_build": ROOT / "fmu_build"}
# Shipped inside every FMU and loaded there on its own: it may import nothing of mbdfmu.
# (The scene FMU's model module runs there as a submodule of the runtime package: its
# ``from . import`` is the runtime's.)
STANDALONE = ("mbdfmu.fmu_build.runtime", "mbdfmu.fmu_build.scene_model")
RUNTIME_SUBMODULES = {"mbdfmu.fmu_build.scene_model": "mbdfmu.fmu_build"}
MAX_MODULE_LINES, MAX_CLASS_LINES, MAX_FUNCTION_LINES = 400, 250, 60


def _modules() -> dict[str, Path]:
    """Every module of the package by its dotted name (fmu_build/ as mbdfmu.fmu_build)."""
    out = {}
    for package, root in SOURCES.items():
        for path in root.rglob("*.py"):
            if "__pycache__" in path.parts:
                continue
            parts = path.relative_to(root).with_suffix("").parts
            if package == "mbdfmu" and parts[0] == "fmu_build":
                continue
            name = ".".join((package, *parts))
            out[name.removesuffix(".__init__")] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    """The mbdfmu modules ``name`` imports (anywhere in the file, lazily or not)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = ".".join(base[:len(base) - node.level + 1])
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module or ""
            found.add(target)
            found |= {f"{target}.{a.name}" for a in node.names}
    return {_resolve(t) for t in found if t.split(".")[0] == "mbdfmu"} - {None}


def _resolve(target: str) -> str | None:
    """The module a dotted import target names (an attribute import names its module)."""
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def _layers() -> list[list[str]]:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = text.split("<!-- layers:")[1].split("<!-- end layers -->")[0]
    rows = [line for line in block.splitlines() if line.startswith("| ") and "`" in line]
    return [re.findall(r"`([\w.]+)`", row.split("|")[2]) for row in rows]


LAYERS = _layers()


def _layer(module: str) -> int:
    """The index of the most specific layer entry that holds ``module``."""
    best, depth = None, -1
    for k, entries in enumerate(LAYERS):
        for entry in entries:
            if (module == entry or module.startswith(entry + ".")) and entry.count(".") > depth:
                best, depth = k, entry.count(".")
    assert best is not None, f"{module} is in no layer of docs/architecture.md"
    return best


def test_every_module_is_in_a_layer_and_imports_only_its_own_or_lower_layers():
    wrong = []
    for name, path in MODULES.items():
        if name.startswith(STANDALONE):
            continue
        for target in _imports(name, path):
            if _layer(target) > _layer(name):
                wrong.append(f"{name} ({LAYERS[_layer(name)][0]}) imports {target} "
                             f"({LAYERS[_layer(target)][0]})")
    assert not wrong, "\n".join(wrong)


def test_what_ships_inside_fmus_imports_nothing_of_mbdfmu():
    for name, path in MODULES.items():
        own = next((p for p in STANDALONE if name.startswith(p)), None)
        if own is not None:
            outside = {m for m in _imports(name, path) if not m.startswith(own)
                       and m != RUNTIME_SUBMODULES.get(name)}
            assert not outside, f"{name} imports {outside}"


def test_there_is_no_import_cycle():
    graph = {name: _imports(name, path) - {name} for name, path in MODULES.items()}
    # a package imports its submodules when they are imported: that is not a cycle
    state: dict[str, int] = {}

    def visit(node, trail):
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt.startswith(node + "."):
                continue
            if state.get(nxt) == 1:
                raise AssertionError("import cycle: " + " -> ".join(trail + [node, nxt]))
            if nxt not in state:
                visit(nxt, trail + [node])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])


def test_modules_classes_and_functions_stay_readable():
    big = []
    for name, path in MODULES.items():
        text = path.read_text(encoding="utf-8")
        if len(text.splitlines()) > MAX_MODULE_LINES:
            big.append(f"module {name}: {len(text.splitlines())} lines")
        for node in ast.walk(ast.parse(text)):
            size = getattr(node, "end_lineno", 0) - getattr(node, "lineno", 0) + 1
            if isinstance(node, ast.ClassDef) and size > MAX_CLASS_LINES:
                big.append(f"class {name}.{node.name}: {size} lines")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and \
                    size > MAX_FUNCTION_LINES:
                big.append(f"function {name}.{node.name}: {size} lines")
    assert not big, "\n".join(big)


def test_nothing_points_outside_the_repository():
    """The project documents its own formulation: no citation of files a clone lacks."""
    pattern = re.compile(r"\.\./shared|shared/[A-Z_]+\.md|seed'?s? eq")
    checked = [*ROOT.glob("README.md"), *(ROOT / "docs").glob("*.md"),
               *(ROOT / "scenes").glob("*"), *(ROOT / "scenarios").rglob("*.*"),
               *MODULES.values()]
    bad = [f"{p.relative_to(ROOT)}:{k + 1}" for p in checked if p.is_file()
           and p.suffix in (".md", ".py", ".toml")
           for k, line in enumerate(p.read_text(encoding="utf-8").splitlines())
           if pattern.search(line)]
    assert not bad, "\n".join(bad)


def test_docs_variable_list_is_generated_from_the_table():
    from mbdfmu.model.variable_docs import markdown_table

    path = ROOT / "docs" / "variables.md"
    text = path.read_text(encoding="utf-8")
    head, rest = text.split("<!-- generated: variables -->\n")
    tail = rest.split("<!-- end generated -->")[1]
    expected = head + "<!-- generated: variables -->\n" + markdown_table() + \
        "<!-- end generated -->" + tail
    if os.environ.get("MBDFMU_REGENERATE_DOCS") == "1":
        path.write_text(expected, encoding="utf-8")
    assert text == expected, ("docs/variables.md is stale: MBDFMU_REGENERATE_DOCS=1 "
                              "python -m pytest tests/test_architecture.py")


HOST = textwrap.dedent("""
    import sys
    from fmpy import simulate_fmu
    res = simulate_fmu({fmu!r}, stop_time=0.01, output_interval=1e-3)
    heavy = sorted({{m.split(".")[0] for m in sys.modules}} & {{"matplotlib", "dask", "numba",
                                                              "distributed", "tqdm"}})
    print(len(res), ",".join(heavy))
""")


@pytest.fixture(scope="module")
def slider_crank_fmu(tmp_path_factory):
    from mbdfmu.fmu_build import build
    return build(ROOT / "scenes" / "slider_crank.toml",
                 tmp_path_factory.mktemp("arch") / "SliderCrank.fmu")


def test_a_built_fmu_carries_no_benchmark_plotting_cosim_or_cli_code(slider_crank_fmu):
    with zipfile.ZipFile(slider_crank_fmu) as z:
        names = z.namelist()
    core = [n for n in names if "/_mbdfmu_" in n]
    assert any(n.endswith("/simulation.py") for n in core)
    for unwanted in ("/bench/", "/cosim/", "/plotting.py", "/cli.py", "/fmu_build/"):
        assert not [n for n in core if unwanted in n], unwanted


def test_loading_and_stepping_an_fmu_imports_no_plotting_or_dask(slider_crank_fmu, tmp_path):
    out = subprocess.run([sys.executable, "-c", HOST.format(fmu=str(slider_crank_fmu))],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={k: v for k, v in os.environ.items() if k != "MBDFMU_KERNEL"})
    assert out.returncode == 0, out.stderr
    rows, heavy = out.stdout.split()[0], out.stdout.strip().partition(" ")[2]
    assert int(rows) == 11 and heavy == "", heavy


def test_every_package_and_its_data_files_are_installed():
    """A non-editable install (CI's, a user's) holds only what pyproject.toml lists: every
    folder with an __init__.py is a listed package, and its non-Python files are package
    data (the C sources of the wrapper and the kernel are compiled at `mbdfmu build`)."""
    import tomllib
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = {name: ROOT / path for name, path in config["package-dir"].items()}
    found = {}
    for top, folder in dirs.items():
        for init in folder.rglob("__init__.py"):
            rel = init.parent.relative_to(folder).parts
            found[".".join((top,) + rel)] = init.parent
    missing = sorted(set(found) - set(config["packages"]))
    assert not missing, f"packages missing from pyproject.toml: {missing}"
    data = config["package-data"]
    for name, folder in found.items():
        for path in folder.iterdir():
            if path.suffix in (".c", ".h"):
                assert any(path.match(g) for g in data.get(name, [])), \
                    f"{path.relative_to(ROOT)} is not package data of {name}"
