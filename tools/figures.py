"""The figures committed to this repository: which are stale, and how each is made again.

``docs/figures.toml`` lists every committed figure with the commands that make it and its
inputs (the config file, and the source files whose code computes or draws it), and
records a digest of each input as it was when the figure was last made. A figure is
*stale* when an input's digest no longer matches: its code or its configuration changed
since. Digests ignore comments, docstrings and blank lines (of Python files) and comments
and layout (of TOML files), so a reworded docstring does not make a figure stale; any
change to code or to a value does.

Run from a checkout::

    python tools/figures.py check                 # every figure: current or stale (exit 1 if any is stale)
    python tools/figures.py make FIGURE ...       # run its commands, copy the result, record its inputs
    python tools/figures.py record FIGURE ...     # record its inputs as they are, without remaking it

``make`` runs the commands with this checkout's ``src`` first on the path, in a scratch
folder named ``{work}`` in the manifest; ``record`` is for a figure remade by hand with
the same commands, or after a change that you checked does not alter it.
``tests/test_figures.py`` runs ``check``.
"""

from __future__ import annotations

import argparse
import ast
import glob
import hashlib
import io
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import tokenize
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = os.path.join(ROOT, "docs", "figures.toml")

HEADER = """\
# Every figure committed to this repository: what makes it, and what it is made of.
#
#   python tools/figures.py check             which figures are stale (tests/test_figures.py runs it)
#   python tools/figures.py make FIGURE       remake one: run `make`, copy `output` to `path`, record
#   python tools/figures.py record FIGURE     record its inputs as they are now (no remaking)
#
# `inputs` are paths or globs relative to the repository root: the configuration and every
# source file whose code computes or draws the figure. `digests` are written by the tool:
# one per input file as it was when the figure was last made (comments, docstrings and
# layout do not count). `{work}` in `make` and `output` is a scratch folder.
"""

FIELDS = ("path", "about", "make", "output", "time", "inputs")


def python_code(text: str) -> str:
    """The source without comments, docstrings, blank lines and trailing spaces: the part
    that changes what the code does (the same on every Python version).

    >>> python_code('\"\"\"Doc.\"\"\"\\n\\nx = 1  # one\\n\\n\\ndef f():\\n    \"\"\"Doc.\"\"\"\\n    return x\\n')
    'x = 1\\ndef f():\\n    return x'
    """
    lines = text.splitlines()
    drop: list[tuple[int, int, int, int]] = []  # (start line, col, end line, col), 1-based lines
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type == tokenize.COMMENT:
            drop.append((*tok.start, *tok.end))
    for node in ast.walk(ast.parse(text)):
        body = getattr(node, "body", None)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body:
            first = body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                drop.append((first.lineno, first.col_offset, first.end_lineno, first.end_col_offset))
    for l0, c0, l1, c1 in sorted(drop, reverse=True):  # from the end, so earlier positions hold
        if l0 == l1:
            lines[l0 - 1] = lines[l0 - 1][:c0] + lines[l0 - 1][c1:]
        else:
            lines[l0 - 1 : l1] = [lines[l0 - 1][:c0] + lines[l1 - 1][c1:]]
    return "\n".join(line.rstrip() for line in lines if line.strip())


def digest(path: str) -> str:
    """A digest of what the file at ``path`` (relative to the root) says, not how it says it."""
    with open(os.path.join(ROOT, path), "rb") as f:
        data = f.read()
    if path.endswith(".py"):
        data = python_code(data.decode("utf-8")).encode()
    elif path.endswith(".toml"):
        data = json.dumps(tomllib.loads(data.decode("utf-8")), sort_keys=True).encode()
    return hashlib.sha256(data).hexdigest()[:16]


def load() -> list[dict]:
    manifest = MANIFEST
    with open(manifest, "rb") as f:
        figures = tomllib.load(f).get("figure", [])
    for fig in figures:
        missing = [k for k in ("path", "make", "inputs") if k not in fig]
        if missing:
            raise SystemExit(f"{os.path.relpath(manifest, ROOT)}: a figure lacks {', '.join(missing)}")
        fig.setdefault("digests", {})
    return figures


def dump(figures: list[dict]) -> None:
    """Write the manifest back in its one layout (the header, then each figure)."""
    manifest = MANIFEST
    out = [HEADER]
    for fig in figures:
        out.append("\n[[figure]]\n")
        for key in FIELDS:
            if key not in fig:
                continue
            value = fig[key]
            if isinstance(value, list):
                out.append(f"{key} = [\n" + "".join(f"  {json.dumps(v)},\n" for v in value) + "]\n")
            else:
                out.append(f"{key} = {json.dumps(value)}\n")
        out.append("\n[figure.digests]\n")
        out.extend(f"{json.dumps(k)} = {json.dumps(v)}\n" for k, v in sorted(fig["digests"].items()))
    tmp = manifest + ".tmp"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write("".join(out))
    os.replace(tmp, manifest)


def input_files(fig: dict) -> list[str]:
    """The files a figure's ``inputs`` name (globs expanded), relative to the root."""
    files = []
    for pattern in fig["inputs"]:
        matched = sorted(glob.glob(pattern, root_dir=ROOT, recursive=True))
        if not matched:
            raise SystemExit(f"{fig['path']}: input {pattern!r} matches no file")
        files += [m.replace(os.sep, "/") for m in matched if m not in files]
    return files


def current(fig: dict) -> dict[str, str]:
    return {path: digest(path) for path in input_files(fig)}


def changes(fig: dict) -> list[str]:
    """What changed since the figure was recorded: one phrase per input; empty if current."""
    now, then = current(fig), fig["digests"]
    if not then:
        return ["never recorded"]
    found = [f"{p} changed" for p in now if p in then and now[p] != then[p]]
    found += [f"{p} is a new input" for p in now if p not in then]
    found += [f"{p} is no longer an input" for p in then if p not in now]
    if not os.path.isfile(os.path.join(ROOT, fig["path"])):
        found.append("the figure file is missing")
    return found


def remake_hint(fig: dict) -> str:
    steps = "; ".join(fig["make"])
    took = f", {fig['time']}" if "time" in fig else ""
    return f"remake it with `python tools/figures.py make {fig['path']}` (runs: {steps}{took})"


def find(figures: list[dict], paths: list[str]) -> list[dict]:
    by_path = {fig["path"]: fig for fig in figures}
    chosen = []
    for path in paths:  # relative to the root, or to the current folder
        key = os.path.normpath(path).replace(os.sep, "/")
        if key not in by_path:
            key = os.path.relpath(os.path.abspath(path), ROOT).replace(os.sep, "/")
        if key not in by_path:
            raise SystemExit(f"{path}: not a figure of {os.path.relpath(MANIFEST, ROOT)} "
                             f"(figures: {', '.join(by_path)})")
        chosen.append(by_path[key])
    return chosen


def command_line(text: str, work: str) -> list[str]:
    """A ``make`` step as an argument list: ``flocking ...`` and ``python ...`` run under
    this interpreter."""
    args = shlex.split(text.replace("{work}", work))
    if args[0] == "flocking":
        return [sys.executable, "-m", "flocking", *args[1:]]
    if args[0] in ("python", "python3"):
        return [sys.executable, *args[1:]]
    return args


def make(fig: dict) -> None:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [os.path.join(ROOT, "src"),
                                                                    os.environ.get("PYTHONPATH")])))
    with tempfile.TemporaryDirectory(prefix="figure-") as work:
        for step in fig["make"]:
            print(f"figures: {step}", file=sys.stderr)
            subprocess.run(command_line(step, work), cwd=ROOT, env=env, check=True)
        if "output" in fig:
            shutil.copyfile(fig["output"].replace("{work}", work), os.path.join(ROOT, fig["path"]))
    fig["digests"] = current(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python tools/figures.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("check", "make", "record"))
    parser.add_argument("figures", nargs="*", help="paths of figures (check, make: all if none)")
    args = parser.parse_args(argv)
    figures = load()
    chosen = find(figures, args.figures) if args.figures else figures
    if args.action == "check":
        stale = 0
        for fig in chosen:
            found = changes(fig)
            stale += bool(found)
            print(f"{fig['path']}: " + (f"stale ({', '.join(found)}); {remake_hint(fig)}" if found else "current"))
        return 1 if stale else 0
    if args.action == "record" and not args.figures:
        parser.error("record: name the figures (record only what you remade or checked)")
    for fig in chosen:
        if args.action == "make":
            make(fig)
        else:
            fig["digests"] = current(fig)
        store(fig)
        print(f"figures: recorded {fig['path']}", file=sys.stderr)
    return 0


def store(fig: dict) -> None:
    """Write ``fig``'s digests into the manifest as it is on disk now: a ``make`` of another
    figure that ran meanwhile (in another shell) keeps what it recorded."""
    figures = load()
    for other in figures:
        if other["path"] == fig["path"]:
            other["digests"] = fig["digests"]
    dump(figures)


if __name__ == "__main__":
    sys.exit(main())
