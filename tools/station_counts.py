"""Four counts of how readable station/ is, computed from the syntax tree (issue 23).

    python tools/station_counts.py [--by-file] [FOLDER]      (FOLDER defaults to station/)

- ``Any``: annotations (of parameters, returns and annotated assignments) that are ``Any``
  itself; ``naming Any`` also counts those with ``Any`` inside (``dict[str, Any]``), one per
  annotation.
- ``local imports``: ``import`` statements inside a function or method body.
- ``unit conversions``: multiplications or divisions by 1e3, 1000, 1e-3 or 0.001, and calls
  of ``degrees``, ``radians``, ``deg2rad`` or ``rad2deg``, in modules other than the format
  and display modules (``DISPLAY`` below: files are written and read, and screens drawn,
  there; a conversion anywhere else is a unit leaving SI inside the program).  ``unit
  conversions (all)`` counts them everywhere.
- ``long functions``: functions and methods of more than 100 lines (``def`` to last line).

Only the standard library, so that anyone can run it on any checkout.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Where mm and degrees belong: the file formats and the screens (the TUI, the HTML report, the
# command line's arguments and printed lines).
DISPLAY = (
    "formats/",
    "tui/",
    "reporting/page.py",
    "commands/",
    "cli.py",
)

_FACTORS = {1e3, 1e-3}  # 1000 and 0.001 compare equal to these
_ANGLE_CALLS = {"degrees", "radians", "deg2rad", "rad2deg"}
_FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef)


def _is_bare_any(node: ast.AST | None) -> bool:
    if isinstance(node, ast.Constant) and node.value == "Any":
        return True
    return isinstance(node, ast.Name | ast.Attribute) and _names_any(node)


def _names_any(node: ast.AST | None) -> bool:
    if node is None:
        return False
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name) and sub.id == "Any":
            return True
        if isinstance(sub, ast.Attribute) and sub.attr == "Any":
            return True
        if isinstance(sub, ast.Constant) and isinstance(sub.value, str) and "Any" in sub.value:
            # a string annotation ("dict[str, Any]")
            try:
                if _names_any(ast.parse(sub.value, mode="eval")):
                    return True
            except SyntaxError:
                pass
    return False


def _is_factor(node: ast.AST) -> bool:
    return (
        isinstance(node, ast.Constant)
        and isinstance(node.value, int | float)
        and not isinstance(node.value, bool)
        and node.value in _FACTORS
    )


def _is_conversion(node: ast.AST) -> bool:
    if isinstance(node, ast.BinOp | ast.AugAssign) and isinstance(node.op, ast.Mult | ast.Div):
        left = node.left if isinstance(node, ast.BinOp) else node.target
        return _is_factor(left) or _is_factor(
            node.right if isinstance(node, ast.BinOp) else node.value
        )
    if isinstance(node, ast.Call):
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        return name in _ANGLE_CALLS
    return False


def counts(path: Path, rel: str) -> Counter[str]:
    """The four counts of one module (unit conversions only outside ``DISPLAY``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    c: Counter[str] = Counter()
    display = any(rel.startswith(d) or rel == d for d in DISPLAY)

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, _FUNCTIONS):
                assert child.end_lineno is not None
                if child.end_lineno - child.lineno + 1 > 100:
                    c["long functions"] += 1
                args = child.args
                every = args.posonlyargs + args.args + args.kwonlyargs
                every += [a for a in (args.vararg, args.kwarg) if a is not None]
                for ann in [a.annotation for a in every] + [child.returns]:
                    c["Any"] += _is_bare_any(ann)
                    c["naming Any"] += _names_any(ann)
                for default in args.defaults + [d for d in args.kw_defaults if d is not None]:
                    visit_stmt(default, in_function)
                for d in child.decorator_list:
                    visit(d, in_function)
                for stmt in child.body:
                    visit_stmt(stmt, True)
                continue
            visit_stmt(child, in_function)

    def visit_stmt(node: ast.AST, in_function: bool) -> None:
        if isinstance(node, ast.Import | ast.ImportFrom) and in_function:
            c["local imports"] += 1
        if isinstance(node, ast.AnnAssign):
            c["Any"] += _is_bare_any(node.annotation)
            c["naming Any"] += _names_any(node.annotation)
        if _is_conversion(node):
            c["unit conversions (all)"] += 1
            c["unit conversions"] += not display
        if isinstance(node, _FUNCTIONS):
            wrapper = ast.Module(body=[node], type_ignores=[])
            visit(wrapper, in_function)
            return
        visit(node, in_function)

    visit(tree, False)
    return c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("folder", nargs="?", default=str(ROOT / "station"))
    ap.add_argument("--by-file", action="store_true", help="one line per module with a count")
    args = ap.parse_args(argv)
    top = Path(args.folder)
    total: Counter[str] = Counter()
    for path in sorted(top.rglob("*.py")):
        rel = path.relative_to(top).as_posix()
        c = counts(path, rel)
        total += c
        if args.by_file and any(c.values()):
            print(f"{rel:40s} " + "  ".join(f"{k} {v}" for k, v in sorted(c.items()) if v))
    keys = ("Any", "naming Any", "local imports", "unit conversions", "unit conversions (all)")
    for key in (*keys, "long functions"):
        print(f"{key:24s} {total[key]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
