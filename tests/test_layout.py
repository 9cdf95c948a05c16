"""The package's rooms stay small enough to read: no source file over 800 lines, and no
function over 100 lines in ``backends/`` and ``rules/``, where the kernels and the rules
are (a kernel's body is read against docs/model.md line by line). Read from the source.
"""

from __future__ import annotations

import ast
import pathlib

import flocking

PACKAGE = pathlib.Path(flocking.__file__).parent

#: most lines of a source file
MAX_FILE = 800
#: most lines of a function (its decorators left out, its docstring counted) in :data:`SHORT`
MAX_FUNCTION = 100
#: the folders whose functions are held to :data:`MAX_FUNCTION`
SHORT = ("backends", "rules")


def long_files(root: pathlib.Path) -> dict[str, int]:
    """Each ``.py`` file below ``root`` longer than :data:`MAX_FILE` lines, with its length."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > MAX_FILE:
            found[str(path.relative_to(root))] = lines
    return found


def long_functions(root: pathlib.Path, folders=SHORT) -> dict[str, int]:
    """Each function (nested ones too) in the ``.py`` files of ``folders`` below ``root``
    longer than :data:`MAX_FUNCTION` lines, as ``file:name``, with its length."""
    found = {}
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_FUNCTION:
                        found[f"{path.relative_to(root)}:{node.name}"] = lines
    return found


def test_the_checkers_see_a_long_file_and_a_long_function(tmp_path):
    (tmp_path / "rules").mkdir()
    (tmp_path / "other").mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION))  # f: one line too many
    inner = "".join(f"        y{i} = {i}\n" for i in range(MAX_FUNCTION - 2))  # g: just fits, h within it
    (tmp_path / "rules" / "long.py").write_text(f"def f():\n{body}\n\ndef g():\n    def h():\n{inner}")
    (tmp_path / "other" / "long.py").write_text(f"def f():\n{body}")  # not a short folder
    (tmp_path / "big.py").write_text("x = 1\n" * (MAX_FILE + 1))
    (tmp_path / "fits.py").write_text("x = 1\n" * MAX_FILE)
    assert long_files(tmp_path) == {"big.py": MAX_FILE + 1}
    assert long_functions(tmp_path) == {"rules/long.py:f": MAX_FUNCTION + 1}


def test_no_source_file_over_800_lines():
    assert long_files(PACKAGE) == {}


def test_no_function_over_100_lines_in_the_kernels_and_the_rules():
    assert long_functions(PACKAGE) == {}
