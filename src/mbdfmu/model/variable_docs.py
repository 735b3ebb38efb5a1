"""The variable list of docs/variables.md, written from the variable table (``TABLES``)."""

from __future__ import annotations

from .variables import GLOBAL_OUTPUTS, GRAVITY, MOTION_PARAMETERS, TABLES, Spec


def _doc_row(label: str, kind: str, spec: Spec) -> str:
    """One row of the documentation's variable list."""
    text = spec.description.format(name="<name>", item=_Placeholder(), pos="{pos}",
                                   effort="{effort}", body="<body>", ratio="{ratio}")
    if spec.when in ("limits", "friction"):      # keys that are a list or a table
        text += f" (when the joint has `{spec.when}`)"
    elif spec.when:
        text += f" (when `{spec.when.lstrip('!')}` is {'false' if spec.when[0] == '!' else 'true'})"
    return f"| {label} | {kind} | `<{label.split()[0]}>.{spec.suffix}` | {spec.unit} | {text} |"


def markdown_table() -> str:
    """The variable list of every item type (docs/variables.md is made from it)."""
    rows = ["| item | kind | name | unit | meaning |", "|---|---|---|---|---|"]
    for cls, table in TABLES.items():
        label = getattr(cls, "TYPE", cls.__name__.lower())
        for kind in ("parameters", "inputs", "outputs"):
            rows += [_doc_row(label, kind[:-1], s) for s in getattr(table, kind)]
    for motion, specs in MOTION_PARAMETERS.items():
        rows += [_doc_row(f"driver ({motion.__name__})", "parameter", s) for s in specs]
    rows.append("| driver (PolynomialMotion) | parameter | `<driver>.c<k>` | {pos}/s<k> | "
                "coefficient of t^k |")
    rows += [f"| scene | parameter | `gravity.{s.suffix}` | {s.unit} | {s.description} |"
             for s in GRAVITY]
    rows += [f"| scene | output | `{v.name}` | {v.unit} | {v.description} |"
             for v in GLOBAL_OUTPUTS]
    return "\n".join(rows) + "\n"


class _Placeholder:
    """Stands for an item in the documentation's descriptions (``{item.body_j}``)."""

    def __getattr__(self, name: str) -> str:
        return f"<{name}>"
