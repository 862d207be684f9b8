"""Functions a reader holds on one screen: no function in thermonet/ is longer than
:data:`MAX_LINES` lines (``def`` to its last line, docstring included), except those named
in :data:`ALLOWED`, each with its reason.  The allow-list is checked both ways: an entry
that is no longer over the limit (or no longer exists) fails too, so the list only shrinks."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80

_C_TEXT = "emits generated C text: one template read top to bottom"

#: "path:qualified name" -> why it may be longer
ALLOWED: dict[str, str] = {
    "thermonet/exporting/c_recurrent.py:render_recurrent_stream_c": _C_TEXT,
    "thermonet/exporting/c_stream_render.py:render_stream_c": _C_TEXT,
    "thermonet/models/cgen.py:c_target_prelude": _C_TEXT,
    "thermonet/exporting/c_header.py:_render_single": _C_TEXT,
    "thermonet/exporting/c_header.py:render_axis_models_c": _C_TEXT,
}


def _long_functions() -> dict[str, int]:
    """``path:qualified name`` -> length in lines, for every function over the limit."""
    found: dict[str, int] = {}

    def visit(node: ast.AST, path: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    n = (child.end_lineno or child.lineno) - child.lineno + 1
                    if n > MAX_LINES:
                        found[f"{path}:{name}"] = n
                visit(child, path, name + ".")
            else:
                visit(child, path, prefix)

    for file in sorted((ROOT / "thermonet").rglob("*.py")):
        rel = file.relative_to(ROOT).as_posix()
        visit(ast.parse(file.read_text(encoding="utf-8")), rel, "")
    return found


def test_no_function_is_longer_than_a_screen():
    long = {k: n for k, n in _long_functions().items() if k not in ALLOWED}
    assert not long, (f"functions over {MAX_LINES} lines (split them into named steps, or add "
                      f"them to ALLOWED with a reason): {long}")


def test_the_allow_list_holds_only_long_functions():
    found = _long_functions()
    stale = sorted(k for k in ALLOWED if k not in found)
    assert not stale, f"no longer over {MAX_LINES} lines (remove from ALLOWED): {stale}"


def test_the_scan_measures_what_it_says(tmp_path):
    """The measure itself on known text: a 3-line function and a nested 81-line one."""
    body = "\n".join(f"    x{i} = {i}" for i in range(79))
    tree = ast.parse(f"def short():\n    a = 1\n    return a\n\n\nclass K:\n"
                     f"    def long(self):\n{body.replace(chr(10) + '    ', chr(10) + '        ')}"
                     "\n        return 0\n".replace("    x0", "        x0", 1))
    sizes = {n.name: n.end_lineno - n.lineno + 1 for n in ast.walk(tree)
             if isinstance(n, ast.FunctionDef)}
    assert sizes == {"short": 3, "long": 81}
