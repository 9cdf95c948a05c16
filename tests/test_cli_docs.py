"""The README's two commands and what it says they produce: CI runs its test command as
written, the folder it lists is the one `flocking run` leaves, its links exist; every
`flocking` command quoted in the documentation uses options that exist."""

import glob
import os
import re

import pytest
from click.testing import CliRunner

from flocking.cli import main
from flocking.cli.run import COMPILE_TIME

ROOT = os.path.join(os.path.dirname(__file__), os.pardir)
README = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()


def blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def test_there_are_two_commands_and_ci_runs_the_second_as_written():
    install, tests = blocks("bash")
    assert install.splitlines()[0] == tests.splitlines()[0]  # both make the virtual environment the same way
    assert install.rstrip().endswith(".venv/bin/flocking run")
    assert tests.rstrip().endswith(".venv/bin/python -m pytest")
    ci = open(os.path.join(ROOT, ".ci", "run"), encoding="utf-8").read()
    assert tests in ci


def test_the_folder_listed_is_the_one_flocking_run_leaves(tmp_path, monkeypatch):
    (listing,) = blocks("console")
    command, *names = listing.strip().splitlines()
    assert command == "$ ls -1 runs/run-0001"
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, ["run", "--steps", "20", "-q"])  # the default run, shorter
    assert result.exit_code == 0, result.output
    assert names == sorted(os.listdir(tmp_path / "runs" / "run-0001"))
    table = re.findall(r"^\| `([^`]+)` \|", README, flags=re.M)
    assert sorted(table) == names


def test_every_link_leads_to_a_file_of_the_repository():
    links = re.findall(r"\]\(([^)]+)\)", README)
    assert len(links) >= 10
    for link in links:
        assert "://" not in link and os.path.exists(os.path.join(ROOT, link.split("#")[0])), link


def test_the_compile_time_said_is_the_one_flocking_run_says():
    assert COMPILE_TIME in " ".join(README.split())


DOCUMENTS = sorted({os.path.relpath(p, ROOT) for p in [os.path.join(ROOT, "README.md"),
                    *glob.glob(os.path.join(ROOT, "docs", "*.md")), *glob.glob(os.path.join(ROOT, "examples", "*.md")),
                    *glob.glob(os.path.join(ROOT, "examples", "*.toml")), os.path.join(ROOT, "docs", "figures.toml")]})


def quoted_commands(text: str):
    """``(command, options)`` of every ``flocking COMMAND ...`` in ``text``: on a line of a
    code block or in inline code, up to a comment; not those shown with the error they make
    (a line ``Error: ...`` after them)."""
    for match in re.finditer(r"(?:^|[`\s\"])(?:\.venv/bin/)?flocking (\w[\w-]*)((?:[^`#\n\"]|\n +\[)*)", text):
        if not text[match.end():].startswith("\nError: "):
            yield match.group(1), re.findall(r"(?<![\w-])--?[a-z][\w-]*", match.group(2))


@pytest.mark.parametrize("document", DOCUMENTS)
def test_every_command_quoted_uses_options_that_exist(document):
    text = open(os.path.join(ROOT, document), encoding="utf-8").read()
    for name, used in quoted_commands(text):
        command = main.get_command(None, name)
        if command is None:  # "flocking run" in prose is a command; other words after "flocking" are not
            assert name not in ("runs", "animates"), (document, name)
            continue
        known = {o for p in command.params for o in p.opts + p.secondary_opts} | {"-h", "--help"}
        unknown = [o for o in used if o not in known and not re.fullmatch(r"-\d.*", o)]
        assert not unknown, (document, name, unknown)
