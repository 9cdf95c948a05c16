"""Committed figures are current: each is listed in docs/figures.toml and made from inputs that
have not changed since (tools/figures.py); the tool itself finds every kind of change."""

import os
import re
import subprocess

import pytest
from scripts import load_script

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
figures = load_script("tools/figures.py")

IMAGES = (".png", ".svg", ".gif", ".jpg", ".pdf")


@pytest.mark.parametrize("fig", figures.load(), ids=lambda f: f["path"])
def test_committed_figure_is_current(fig):
    found = figures.changes(fig)
    assert not found, f"{fig['path']} is stale ({', '.join(found)}): {figures.remake_hint(fig)}"


def test_every_figure_of_the_docs_is_in_the_manifest():
    listed = {fig["path"] for fig in figures.load()}
    build = os.path.join(ROOT, "docs", "_build")  # the built site's copies (gitignored), not figures
    on_disk = {os.path.relpath(os.path.join(d, f), ROOT).replace(os.sep, "/")
               for top in ("docs", "examples") for d, _, names in os.walk(os.path.join(ROOT, top))
               if not os.path.realpath(d).startswith(os.path.realpath(build))
               for f in names if f.endswith(IMAGES)}
    shown = set()
    for d, _, names in os.walk(ROOT):
        if any(part.startswith((".", "_build")) for part in os.path.relpath(d, ROOT).split(os.sep)) or "src" in d:
            continue
        for name in names:
            if name.endswith(".md"):
                text = open(os.path.join(d, name), encoding="utf-8").read()
                for target in re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text):
                    shown.add(os.path.relpath(os.path.normpath(os.path.join(d, target)), ROOT).replace(os.sep, "/"))
    assert on_disk | shown <= listed, f"figures missing from docs/figures.toml: {sorted((on_disk | shown) - listed)}"
    assert all(os.path.isfile(os.path.join(ROOT, p)) for p in listed)


def test_code_digest_ignores_comments_docstrings_and_blank_lines():
    code = 'x = 1\n\n\ndef f(a):\n    return a + x\n'
    same = '"""Module."""\n# a comment\nx = 1  # one\n\ndef f(a):\n    """Doc\n    on two lines."""\n    return a + x\n'
    assert figures.python_code(code) == figures.python_code(same)
    for changed in ('x = 2\n\ndef f(a):\n    return a + x\n', 'x = 1\n\ndef f(a):\n    return a - x\n',
                    'x = 1\n\ndef f(a):\n    s = "# not a comment"\n    return a + x\n'):
        assert figures.python_code(changed) != figures.python_code(code)


@pytest.fixture
def repo(tmp_path, monkeypatch):
    """A tiny repository: one figure made by a script from a config."""
    (tmp_path / "docs").mkdir()
    (tmp_path / "draw.py").write_text("import sys\nopen(sys.argv[2], 'w').write(open(sys.argv[1]).read())\n")
    (tmp_path / "fig.toml").write_text("# the colour\ncolour = 'red'\n")
    (tmp_path / "docs" / "figures.toml").write_text(
        '[[figure]]\npath = "fig.txt"\nmake = ["python draw.py fig.toml {work}/out.txt"]\n'
        'output = "{work}/out.txt"\ninputs = ["fig.toml", "*.py"]\n')
    monkeypatch.setattr(figures, "ROOT", str(tmp_path))
    monkeypatch.setattr(figures, "MANIFEST", str(tmp_path / "docs" / "figures.toml"))
    return tmp_path


def check(capsys):
    code = figures.main(["check"])
    return code, capsys.readouterr().out


def test_make_record_and_every_kind_of_staleness(repo, capsys):
    code, out = check(capsys)
    assert code == 1 and "fig.txt: stale (never recorded); remake it with `python tools/figures.py make fig.txt`" in out
    assert figures.main(["make", str(repo / "fig.txt")]) == 0
    assert "colour = 'red'" in (repo / "fig.txt").read_text()
    assert check(capsys) == (0, "fig.txt: current\n")
    # comments and layout of the config do not matter; a value does
    (repo / "fig.toml").write_text("colour = 'red'   # still red\n")
    assert check(capsys)[0] == 0
    (repo / "fig.toml").write_text("colour = 'blue'\n")
    code, out = check(capsys)
    assert code == 1 and "stale (fig.toml changed)" in out and "python draw.py fig.toml {work}/out.txt" in out
    assert figures.main(["record", str(repo / "fig.txt")]) == 0  # e.g. remade by hand
    assert check(capsys)[0] == 0
    # a new source file under an input glob, then a removed one
    (repo / "helper.py").write_text("y = 2\n")
    assert "helper.py is a new input" in check(capsys)[1]
    figures.main(["record", "fig.txt"])
    (repo / "helper.py").unlink()
    assert "helper.py is no longer an input" in check(capsys)[1]
    figures.main(["record", "fig.txt"])
    (repo / "fig.txt").unlink()
    assert "the figure file is missing" in check(capsys)[1]


def test_manifest_errors_name_the_problem(repo):
    with pytest.raises(SystemExit, match="not a figure of docs/figures.toml"):
        figures.main(["record", "nowhere.png"])
    (repo / "docs" / "figures.toml").write_text('[[figure]]\npath = "x.png"\nmake = []\ninputs = ["gone/*.py"]\n')
    with pytest.raises(SystemExit, match="input 'gone/\\*.py' matches no file"):
        figures.main(["check"])
    (repo / "docs" / "figures.toml").write_text('[[figure]]\npath = "x.png"\n')
    with pytest.raises(SystemExit, match="a figure lacks make, inputs"):
        figures.main(["check"])


def test_a_failing_command_records_nothing(repo):
    (repo / "draw.py").write_text("raise SystemExit(3)\n")
    with pytest.raises(subprocess.CalledProcessError) as failed:
        figures.main(["make", "fig.txt"])
    assert failed.value.returncode == 3
    assert "digests" not in (repo / "docs" / "figures.toml").read_text()


def test_a_make_keeps_what_another_make_recorded_meanwhile(repo, capsys, monkeypatch):
    (repo / "docs" / "figures.toml").write_text(
        (repo / "docs" / "figures.toml").read_text()
        + '\n[[figure]]\npath = "other.txt"\nmake = ["python draw.py fig.toml {work}/out.txt"]\n'
          'output = "{work}/out.txt"\ninputs = ["fig.toml"]\n')
    make = figures.make

    def slow_make(fig):  # while fig.txt is being made, other.txt is made in another shell
        make(fig)
        if fig["path"] == "fig.txt":
            monkeypatch.setattr(figures, "make", make)
            assert figures.main(["make", "other.txt"]) == 0

    monkeypatch.setattr(figures, "make", slow_make)
    assert figures.main(["make", "fig.txt"]) == 0
    assert check(capsys) == (0, "fig.txt: current\nother.txt: current\n")
