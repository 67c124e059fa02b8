"""The README and docs/*.md say only what the tree holds and what the command line accepts.

* every relative link (``[text](path#anchor)``) names a file that exists, and its anchor a heading
  of that file (also in results/README.md and each results folder's README.md);
* every repository path named in code (inline or fenced: ``nmrl/...``, ``scripts/...``,
  ``results/...``, ...) exists, in the docs and the results' READMEs alike; a path with a
  placeholder (``<point>``, ``{md,json}``, ``*``) is a pattern, not a name, and is not checked;
* every ``nmrl ...`` command line in a fenced block parses with nmrl's own argparse parsers, without
  running: ``train``, ``sweep`` and ``eval`` with ``nmrl.cli.arguments.build_parser(learner)`` (the learner
  ``--learner`` names, as ``nmrl.cli.main`` builds it), ``baseline`` and ``study`` with the parser
  their ``main`` builds (caught before it parses); a command named in a sentence (inline code, e.g.
  ``nmrl train --resume``) names only options that exist;
* the README's "What is where" names exactly the files of ``nmrl/*/`` (``__init__.py`` aside),
  ``nmrl/pytrees.py`` and ``nmrl/options.py``; the README starts with the two set-up commands, and
  the second is what ``.ci/run`` runs.
"""

from __future__ import annotations

import argparse
import pathlib
import re
import shlex
import unicodedata

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
#: the results' index and the folders' own notes: their links and named paths are checked as the docs'
RESULT_PAGES = [ROOT / "results" / "README.md", *sorted((ROOT / "results").glob("*/README.md"))]
#: top-level entries of the repository a path in the docs may start with
TOP = ("nmrl/", "scripts/", "examples/", "results/", "docs/", "benchmarks/", "tests/", "models/", ".ci/")
PATTERN = re.compile(r"[<>{}*…]|\.\.\.")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
INLINE = re.compile(r"`([^`\n]+)`")


def _text(page: pathlib.Path) -> str:
    return page.read_text(encoding="utf-8")


def _prose(text: str) -> str:
    """The page without its fenced blocks (inline code and links live here)."""
    return FENCE.sub("", text)


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    s = unicodedata.normalize("NFKC", heading.strip().lower())
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def _anchors(page: pathlib.Path) -> set[str]:
    return {_slug(m[1]) for m in re.finditer(r"^#+\s+(.*)$", _prose(_text(page)), re.M)}


def _rel(page: pathlib.Path) -> str:
    return str(page.relative_to(ROOT))


# ----------------------------------------------------------------------------------- links


def _links():
    for page in PAGES + RESULT_PAGES:
        for target in LINK.findall(_prose(_text(page))):
            if not re.match(r"[a-z]+:", target):
                yield pytest.param(page, target, id=f"{_rel(page)}:{target}")


@pytest.mark.parametrize("page,target", list(_links()))
def test_relative_link_exists(page, target):
    path, _, anchor = target.partition("#")
    dest = (page.parent / path).resolve() if path else page
    assert dest.exists(), f"{_rel(page)} links to {target!r}: {dest} does not exist"
    if anchor:
        assert anchor in _anchors(dest), f"{_rel(page)} links to {target!r}: no heading with that anchor"


# ----------------------------------------------------------------------------------- paths


def _path_tokens(text: str):
    spans = INLINE.findall(_prose(text)) + FENCE.findall(text)
    for span in spans:
        for tok in span.split():
            tok = tok.strip("'\"(),;").split("::")[0].rstrip(".:")
            if tok.startswith(TOP) and not PATTERN.search(tok):
                yield tok


def _paths():
    for page in PAGES + RESULT_PAGES:
        for tok in sorted(set(_path_tokens(_text(page)))):
            yield pytest.param(page, tok, id=f"{_rel(page)}:{tok}")


@pytest.mark.parametrize("page,path", list(_paths()))
def test_named_path_exists(page, path):
    assert (ROOT / path).exists(), f"{_rel(page)} names {path!r}, which is not in the tree"


# ----------------------------------------------------------------------------------- commands


def _command_lines(text: str):
    """``(line, from_fence)`` for every line of code that runs ``nmrl``: fenced lines (with ``\\``
    continuations joined) and inline code spans."""
    for block in FENCE.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            yield line, True
    for span in INLINE.findall(_prose(text)):
        yield span, False


def _nmrl_argv(line: str) -> list[str] | None:
    """The arguments after ``nmrl`` in a shell line (comments, ``&``, ``&&``, ``;``, ``|`` end it)."""
    try:
        lex = shlex.shlex(line, posix=True, punctuation_chars="&;|")
        lex.whitespace_split = True
        lex.commenters = "#"
        toks = list(lex)
    except ValueError:
        return None
    for i, t in enumerate(toks):
        if t == "nmrl" or t.endswith("/nmrl"):
            argv = []
            for a in toks[i + 1:]:
                if a in ("&", "&&", ";", "|", "||"):
                    break
                argv.append(a)
            return argv if argv and not argv[0].startswith("-") or argv[:1] == ["--help"] else None
    return None


def _commands():
    for page in PAGES:
        seen = set()
        for line, fenced in _command_lines(_text(page)):
            argv = _nmrl_argv(line)
            if argv is None or tuple(argv) in seen:
                continue
            if PATTERN.search(" ".join(argv)):
                assert not fenced, f"{_rel(page)}: a fenced nmrl command with a placeholder: {line!r}"
            seen.add(tuple(argv))
            yield pytest.param(page, argv, fenced, id=f"{_rel(page)}:nmrl {' '.join(argv)}"[:180])


class _Parsed(Exception):
    def __init__(self, parser: argparse.ArgumentParser):
        super().__init__()
        self.parser = parser


def _top_parser(sub: str, argv: list[str]) -> argparse.ArgumentParser:
    """The parser ``nmrl <sub>`` uses: ``nmrl.cli.arguments.build_parser`` for train/sweep/eval, the one the
    ``main`` of ``baseline``/``study`` builds (caught at its ``parse_args``, before it parses)."""
    if sub in ("train", "sweep", "eval"):
        from nmrl import cli
        from nmrl.cli import arguments, config_options

        learner = config_options.get_learner(cli.learner_name([sub, *argv])) if sub in ("train", "sweep") else None
        return arguments.build_parser(learner)  # as cli.main builds it: with the options of the learner named
    own = {"baseline": "baseline_ppo", "study": "study"}
    if sub not in own:
        pytest.fail(f"nmrl has no command {sub!r}")
    import importlib

    mod = importlib.import_module("nmrl.experiments." + own[sub])
    original = argparse.ArgumentParser.parse_args

    def stop(self, args=None, namespace=None):
        raise _Parsed(self)

    argparse.ArgumentParser.parse_args = stop
    try:
        mod.main(argv)
    except _Parsed as e:
        return e.parser
    finally:
        argparse.ArgumentParser.parse_args = original
    pytest.fail(f"nmrl {sub}'s main returned without parsing its arguments")


def _parse(argv: list[str], capsys) -> None:
    """Parse ``nmrl <argv>`` as nmrl would, without running it; fail with argparse's message."""
    parser = _top_parser(argv[0], argv[1:])
    args = argv if argv[0] in ("train", "sweep", "eval") else argv[1:]
    try:
        parser.parse_args(args)
    except SystemExit as e:
        if e.code != 0:  # --help exits 0
            pytest.fail(f"`nmrl {' '.join(argv)}` does not parse: {capsys.readouterr().err.strip()}")


def _options_exist(argv: list[str]) -> None:
    """For a command named in a sentence (`nmrl train --resume`): every option it names exists."""
    parser = _top_parser(argv[0], argv[1:])
    args = argv if argv[0] in ("train", "sweep", "eval") else argv[1:]
    while args and not args[0].startswith("-"):  # descend into sub-commands (train, baseline ppo, ...)
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or args[0] not in subs[0].choices:
            break
        parser, args = subs[0].choices[args[0]], args[1:]
    for a in args:
        if a.startswith("--"):
            opt = a.split("=")[0]
            assert opt in parser._option_string_actions, f"`nmrl {' '.join(argv)}`: no option {opt}"


@pytest.mark.parametrize("page,argv,fenced", list(_commands()))
def test_nmrl_command_parses(page, argv, fenced, capsys):
    if fenced:
        _parse(argv, capsys)
    else:
        _options_exist(argv)


def test_a_bad_command_would_be_caught(capsys):
    with pytest.raises(pytest.fail.Exception, match="does not parse"):
        _parse(["train", "--no-such-option", "1", "--out", "x"], capsys)
    with pytest.raises(pytest.fail.Exception, match="does not parse"):
        _parse(["study", "--no-such-option"], capsys)
    with pytest.raises(AssertionError, match="no option --no-such"):
        _options_exist(["baseline", "ppo", "--no-such"])
    _options_exist(["baseline", "ppo", "--resume", "--num-timesteps"])
    assert _nmrl_argv("srun .venv/bin/nmrl sweep --l 1 --out o --resume & # note") == ["sweep", "--l", "1", "--out",
                                                                                       "o", "--resume"]


# ----------------------------------------------------------------------------------- README


def _section(text: str, title: str) -> str:
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert m, f"README has no section '## {title}'"
    return m[1]


def test_what_is_where_matches_the_tree():
    named = {n for n in re.findall(r"`(nmrl/[\w/.]+)`", _section(_text(ARCHITECTURE), "What is where"))
             if not n.endswith("/")}  # a package's name; its files are the rows
    tree = {str(p.relative_to(ROOT)) for p in (ROOT / "nmrl").glob("*/*")
            if p.name not in ("__init__.py", "__pycache__")} | {"nmrl/pytrees.py", "nmrl/options.py"}
    assert sorted(tree - named) == [], "in the tree, not in docs/architecture.md"
    assert sorted(named - tree) == [], "in docs/architecture.md, not in the tree"


def test_readme_starts_with_the_two_commands_and_ci_runs_the_second():
    first = FENCE.search(_text(README))[1].splitlines()
    head = _text(README).lstrip()
    assert head.startswith("# nmrl\n\n") and "```bash\n" in head[:400]  # a line of what it is, then the commands
    assert len(first) == 2 and first[0].startswith("python3 -m venv .venv && .venv/bin/pip install -c requirements.lock -e '.[dev]' && ")
    assert first[1] == ".venv/bin/python -m pytest -q"
    ci = [l.strip() for l in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert first[1] in ci


def test_readme_is_a_front_page():
    assert len(_text(README).splitlines()) <= 200


def test_runs_page_lists_every_exit_status_as_the_code_does():
    from nmrl.runs import exits

    text = _text(ROOT / "docs" / "runs.md")
    table = text[text.index("| status | meaning |"):]
    rows = dict(re.findall(r"^\| (\d+) \| (.*) \|$", table, re.M))
    assert {int(k): v for k, v in rows.items()} == exits.TABLE
