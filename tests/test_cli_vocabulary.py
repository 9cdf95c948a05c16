"""One vocabulary on the command line: every option of every subcommand, walked from the
commands themselves; one line for every usage error."""

import re
import shlex

import click
import pytest
from click.testing import CliRunner

from flocking.cli import main, options
from flocking.model import ParameterError

COMMANDS = dict(main.commands)

#: concept -> (option, type, choices or None, default): what every subcommand that takes it
#: must declare (tests/test_cli.py checks that the defaults shown are those used)
CONCEPTS = {
    "output": ("--out", click.STRING, None, None),
    "picture format": ("--format", options.OneOf, ("png", "svg", "pdf"), "png"),
    "theme": ("--theme", options.OneOf, ("dark", "light"), "dark"),
    "size": ("--size", options.OneOf, ("column", "page", "slide"), "page"),
    "resolution": ("--dpi", click.FLOAT, None, None),
    "colour": ("--color", options.OneOf, ("auto", "heading", "species", "deviation"), "auto"),
    "backend": ("--backend", options.OneOf, ("cpu", "cuda", "reference"), None),
    "quiet": ("--quiet", click.BOOL, None, False),
}
#: which subcommands take each concept
TAKEN_BY = {
    "output": {"run", "animate", "analyze", "sweep", "plot-sweep", "bench"},
    "picture format": {"run", "analyze"},
    "theme": {"run", "animate", "analyze", "plot-sweep"},
    "size": {"animate", "analyze", "plot-sweep"},
    "resolution": {"run", "animate", "analyze", "plot-sweep"},
    "colour": {"run", "animate"},
    "backend": {"run", "sweep"},
    "quiet": {"run", "animate", "analyze", "sweep", "plot-sweep"},
}
#: names that once meant these concepts: none may come back
RETIRED = {"--output", "--plot-format"}
#: names that meant two things, now each in the subcommands where it means one
ONE_MEANING = {"--start": {"analyze"}, "--stop": set(), "--radius": {"run", "play"}}


def long_options(command):
    return {o: p for p in command.params if isinstance(p, click.Option) for o in p.opts + p.secondary_opts
            if o.startswith("--")}


def kind(param):
    """An option's type, as far as the vocabulary cares: the class, the choices, flag or not."""
    t = param.type
    return type(t).__name__, tuple(getattr(t, "choices", ()) or ()), param.is_flag, param.multiple


def test_the_shared_choices_are_those_of_the_library():
    from flocking import backends
    from flocking.viz import colors, particles, style

    assert options.THEMES == tuple(colors.THEMES)
    assert options.SIZES == tuple(style.SIZES) and options.FORMATS == style.FORMATS
    assert options.COLORS == colors.COLORS and options.DEFAULT_DPI == style.DPI
    assert set(options.BACKENDS) == set(backends.NAMES)
    assert long_options(COMMANDS["animate"])["--style"].type.choices == particles.STYLES
    for dpi in (9.9, 1000.1, float("nan")):
        with pytest.raises(ParameterError, match="^dpi: must be in"):
            style.check_dpi(dpi)
        assert not options.DPI_RANGE[0] <= dpi <= options.DPI_RANGE[1]
    assert style.check_dpi(options.DPI_RANGE[0]) == 10 and style.check_dpi(options.DPI_RANGE[1]) == 1000


@pytest.mark.parametrize("concept", CONCEPTS)
def test_each_concept_has_one_name_one_type_one_default(concept):
    name, type_, choices, default = CONCEPTS[concept]
    takers = {cmd for cmd, command in COMMANDS.items() if name in long_options(command)}
    assert takers == TAKEN_BY[concept]
    for cmd in takers:
        param = long_options(COMMANDS[cmd])[name]
        assert isinstance(param.type, type_ if isinstance(type_, type) else type(type_)), (cmd, name)
        assert tuple(getattr(param.type, "choices", ()) or ()) == (choices or ()), (cmd, name)
        assert param.default == default, (cmd, name)
        assert param.help and "[default:" in help_line(COMMANDS[cmd], param) or param.is_flag, (cmd, name)


def help_line(command, param) -> str:
    return " ".join(param.get_help_record(click.Context(command, info_name=command.name))[1].split())


def test_an_option_means_one_thing_in_every_subcommand():
    """Walk every option of every subcommand: an option name used by several of them has
    the same type, choices and default in each (the sizes a new play tab starts with are
    play's own, shown in its help)."""
    seen = {}
    for cmd, command in COMMANDS.items():
        for name, param in long_options(command).items():
            assert name not in RETIRED, (cmd, name)
            seen.setdefault(name, []).append((cmd, kind(param), param.default))
    for name, takers in ONE_MEANING.items():
        assert {cmd for cmd, *_ in seen.get(name, [])} == takers, name
    shared = {name: uses for name, uses in seen.items() if len(uses) > 1}
    assert {"--out", "--theme", "--dpi", "--backend", "--quiet", "--noise", "--n", "--host"} <= shared.keys()
    for name, uses in shared.items():
        assert len({(k, d) for _, k, d in uses}) == 1, (name, uses)
    # a short name is one option everywhere too
    shorts = {}
    for cmd, command in COMMANDS.items():
        for param in command.params:
            for o in param.opts:
                if re.fullmatch(r"-\w", o):
                    shorts.setdefault(o, set()).add(next(x for x in param.opts if x.startswith("--")))
    assert shorts == {"-o": {"--out"}, "-q": {"--quiet"}}


def test_flocking_help_has_examples_a_pointer_to_the_docs_and_whole_summaries():
    result = CliRunner().invoke(main, ["--help"], terminal_width=200)
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "Examples:" in result.output and "docs/" in text and "README.md" in text
    listed = result.output.split("Commands:")[1].split("Documentation:")[0]
    lines = [line.split(None, 1) for line in listed.strip().splitlines()]
    assert sorted(name for name, _ in lines) == sorted(COMMANDS)
    for name, summary in lines:
        assert summary.endswith(".") and not summary.endswith("..."), (name, summary)
        assert summary == COMMANDS[name].short_help


def examples(text: str):
    """The ``flocking ...`` lines of a help text's examples, as argument lists."""
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if line.startswith("flocking "):
            yield shlex.split(line)[1:]


@pytest.mark.parametrize("cmd", [None, *COMMANDS])
def test_every_example_in_the_help_uses_options_that_exist(cmd):
    command = main if cmd is None else COMMANDS[cmd]
    found = list(examples(command.help + (command.epilog or "")))
    assert found or cmd in ("bench",)
    for args in found:
        sub = COMMANDS[main.resolve_command(click.Context(main), args)[0]]
        known = long_options(sub).keys() | {"-o", "-q"}
        for token in args[1:]:
            if token.startswith("-") and not re.fullmatch(r"-?[\d.]+", token):
                assert token in known, (args, token)


def usage_errors():
    """(arguments, what the one line says) for a usage error of every kind, in every subcommand."""
    cases = [(["nosuch"], "No such command 'nosuch'"), (["analyzer"], "did you mean 'analyze'?"),
             (["--nosuch"], "--nosuch: no such option of flocking")]
    for cmd, command in COMMANDS.items():
        cases.append(([cmd, "--nosuch-option"], f"--nosuch-option: no such option of flocking {cmd}"))
        required = [p for p in command.params if isinstance(p, click.Argument) and p.required]
        if required:
            cases.append(([cmd], f"Missing argument '{required[0].human_readable_name}'"))
        filler = ["x"] * len(required)
        choice = next((p for p in command.params if isinstance(p.type, click.Choice)), None)
        if choice is not None:
            cases.append(([cmd, *filler, choice.opts[0], "nonsense"],
                          f"{choice.opts[0]}: must be one of {', '.join(choice.type.choices)} (got 'nonsense')"))
        number = next((p for p in command.params if p.type in (click.INT, click.FLOAT)), None)
        if number is not None:
            cases.append(([cmd, *filler, number.opts[0], "many"], f"{number.opts[0]}: 'many' is not a valid"))
        flag = next((p for p in command.params if isinstance(p, click.Option) and p.is_flag and not p.secondary_opts
                     and p.name not in ("help",)), None)
        if flag is not None:
            cases.append(([cmd, *filler, f"{flag.opts[0]}=yes"], f"Option '{flag.opts[0]}' does not take a value"))
    return cases


@pytest.mark.parametrize("args, message", usage_errors(), ids=lambda x: " ".join(x) if isinstance(x, list) else "")
def test_every_usage_error_is_one_line_and_exit_code_2(tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert result.output.startswith("Error: ") and message in result.output, result.output
    assert len(result.output.splitlines()) == 1 and "Usage:" not in result.output
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_option_gets_the_closest_one():
    result = CliRunner().invoke(main, ["run", "--obstacles", "16,16,4"])
    assert result.output == ("Error: --obstacles: no such option of flocking run; did you mean --obstacle? "
                             "(flocking run --help lists them)\n")
    result = CliRunner().invoke(main, ["animate", "r", "--output", "x.mp4"])
    assert "did you mean --out?" in result.output and result.exit_code == 2


# --- the documentation's vocabulary: every option and config key a page names exists ----

import glob  # noqa: E402
import os  # noqa: E402
import tomllib  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), os.pardir)
PAGES = sorted(os.path.relpath(p, ROOT) for p in [*glob.glob(os.path.join(ROOT, "docs", "*.md")),
                                                  os.path.join(ROOT, "examples", "README.md"),
                                                  os.path.join(ROOT, "README.md"),
                                                  os.path.join(ROOT, "ARCHITECTURE.md")])
#: options of other programs that the pages quote, with the program each belongs to
OTHER_PROGRAMS = {"--nworkers": "dask worker", "--nthreads": "dask worker", "--without-pip": "venv",
                  "--system-site-packages": "venv"}


def page_text(page: str) -> str:
    return open(os.path.join(ROOT, page), encoding="utf-8").read()


def code_spans(text: str) -> list[str]:
    """The code a page shows: each line of its fenced blocks, each inline code span; not a
    line shown with the error it makes (a line ``Error: ...`` after it), nor that error."""
    fenced = re.findall(r"```[\w-]*\n(.*?)```", text, flags=re.S)
    lines = [line for block in fenced for line, after in zip(block.splitlines(), block.splitlines()[1:] + [""])
             if not after.startswith("Error: ") and not line.startswith("Error: ")]
    inline = re.findall(r"(?<!`)`([^`\n]+)`(?!`)", re.sub(r"```.*?```", "", text, flags=re.S))
    return lines + inline


def script_options() -> set[str]:
    """The options of the repository's own scripts (benchmarks, examples, tools)."""
    found = set()
    for path in [*glob.glob(os.path.join(ROOT, "benchmarks", "*.py")), *glob.glob(os.path.join(ROOT, "examples", "*.py")),
                 *glob.glob(os.path.join(ROOT, "tools", "*.py")), os.path.join(ROOT, "docs", "model_figures.py")]:
        found |= set(re.findall(r"add_argument\(\s*['\"](--[\w-]+)", open(path, encoding="utf-8").read()))
    return found


def unknown_options(text: str, known: set[str]) -> list[str]:
    bad = []
    for span in code_spans(text):
        for option in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", span):
            program = OTHER_PROGRAMS.get(option)
            if option not in known and not (program and program in span):
                bad.append(option)
    return bad


def test_every_option_a_page_names_exists():
    """An option quoted anywhere in the documentation, in a command or alone in prose, is an
    option of a flocking command, of one of the repository's scripts, or of the other program
    quoted with it (a renamed or removed option fails here)."""
    known = {o for c in COMMANDS.values() for p in c.params for o in p.opts + p.secondary_opts}
    known |= {"--help", "--version"} | script_options()
    assert {"--out", "--species-b", "--cross-coupling", "--full", "--rounds"} <= known
    for page in PAGES:
        assert unknown_options(page_text(page), known) == [], page
    # and the check bites: a retired name, a misspelling, another program's option out of place
    assert unknown_options("`flocking run --output x` or `--obstacles 1,1,1`", known) == ["--output", "--obstacles"]
    assert unknown_options("run it with `--nthreads 1`", known) == ["--nthreads"]
    assert unknown_options("```\nflocking run --obstacles 16,16,4\nError: no such option\n```", known) == []


def test_every_config_key_a_page_names_exists():
    """The parameter tables of model.md and extensions.md name keys of config.toml; every TOML
    block of the pages is a valid run config or sweep file; an inline ``key = "value"`` or
    ``key = true`` is a key of one of them."""
    from flocking.config import RUN_KEYS, RunConfig
    from flocking.sweep.spec import RANGE_KEYS, SWEEP_DEFAULTS, SweepSpec

    rows = {page: re.findall(r"^\| `([a-z_]+)` \|", page_text(page), flags=re.M)
            for page in ("docs/model.md", "docs/extensions.md")}
    assert len(rows["docs/model.md"]) >= 15 and len(rows["docs/extensions.md"]) >= 10
    for page, keys in rows.items():
        assert set(keys) <= set(RUN_KEYS), (page, set(keys) - set(RUN_KEYS))
    blocks = [(page, block) for page in PAGES for block in re.findall(r"```toml\n(.*?)```", page_text(page), flags=re.S)]
    assert len(blocks) >= 3
    for page, block in blocks:
        text = "\n".join(line[2:] if line.startswith("  ") else line for line in block.splitlines())
        data = tomllib.loads(text)
        if {"sweep", "base", "grid"} & data.keys():
            SweepSpec.from_toml(text)
        else:
            RunConfig.from_dict(data)
    allowed = set(RUN_KEYS) | set(SWEEP_DEFAULTS) | set(RANGE_KEYS)
    for page in PAGES:
        for span in code_spans(page_text(page)):
            m = re.fullmatch(r'\s*([a-z_]+) = ("[^"]*"|true|false)\s*(#.*)?', span)
            if m:
                assert m[1] in allowed, (page, span)
    with pytest.raises(ParameterError, match="unknown parameter"):
        RunConfig.from_dict({"noise_kind": "angular"})
