"""Every ``swarmd ...`` / ``swarmctl ...`` command line the operator docs show parses.

A newcomer copies these lines. They were written over many sessions while the CLIs changed,
so each one is taken from the docs' code blocks and inline code and given to the real
parsers (``build_parser()`` of ``swarmd/cli/swarmctl.py`` and ``swarmd/cli/swarmd_main.py``):
parse only, nothing runs. A failure names the doc, the line and the parser's complaint.

How a line becomes a command (``doc_commands``):

- shell lines of fenced blocks (```` ``` ````, ```` ```sh ````; not json/yaml/python),
  continuation lines joined; in a block with ``$`` prompts only the prompted lines are
  commands, the rest is output;
- inline code spans, a span may wrap over a line break; ``\\|`` (a pipe in a table cell) is
  a pipe;
- the shell around them: ``sudo``, ``ssh [-opts] HOST``, ``VAR=value``, ``for ...; do``,
  ``a | jq ...``, ``a && b``, ``# comments``, ``> file`` redirections, a path to the program
  (``.venv/bin/swarmctl``);
- synopsis notation: ``[--json]`` is the option given, ``land | hold | abort`` and
  ``--serial 5|6`` are each alternative, ``NODE...`` one value;
- placeholders: a number where the option wants one (``S``, ``N``, ``M``, ``SECONDS``,
  ``ID``), ``<name>`` its name, any other CAPITALS left as the string they are;
- a mention (``swarmd run``: the program and its subcommands, nothing else) or a line with an
  elision (``swarmctl px4 key ... --out``) is checked for its subcommands, options and
  values, not for the required arguments it leaves out.

Options are matched in full (``allow_abbrev`` off): a prefix that parses today breaks when an
option sharing it is added.

Also: every swarmctl (and swarmd) subcommand and option appears in a command line of
docs/operations.md, and every exit code the CLIs' docstrings and help name is a row of
operations.md's exit-code table, in the column of the program that returns it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import pytest

from swarmd import exitcodes
from swarmd.cli import swarmctl, swarmd_main

ROOT: Final = Path(__file__).resolve().parent.parent
DOCS: Final = (
    "README.md",
    "docs/deploy.md",
    "docs/operations.md",
    "docs/preflight.md",
    "docs/px4.md",
    "docs/ros2.md",
    "docs/bundle-format.md",
)
OPERATIONS: Final = "docs/operations.md"
PROGRAMS: Final[dict[str, Callable[[], argparse.ArgumentParser]]] = {
    "swarmctl": swarmctl.build_parser,
    "swarmd": swarmd_main.build_parser,
}
# fenced blocks in these languages hold no shell lines
NOT_SHELL: Final = frozenset({"json", "yaml", "python", "toml", "ini"})
# a word after `|` that starts a pipe's reader (else `a | b` is a synopsis' alternatives)
PIPE_READERS: Final = frozenset(
    {"jq", "head", "tail", "grep", "less", "tee", "sort", "wc", "awk", "sed", "xargs", "cat"}
)
# the words in front of a command that only say where or how it runs
PREFIX_WORDS: Final = frozenset({"sudo", "do", "then", "else", "exec", "time", "command"})
# placeholders that stand for a number (an option with type=float or int)
NUMBER_PLACEHOLDERS: Final = {
    "S": "1",
    "N": "3",
    "M": "5",
    "SECONDS": "3",
    "ID": "0x1",
    "PORT": "7399",
    "SYSID": "1",
}
# doc lines that look like a command and are not one: (doc, text in the line) -> why
SKIPPED: Final[dict[tuple[str, str], str]] = {
    ("docs/px4.md", "swarmd (comp 191)"): "a sequence diagram's column heading",
    ("docs/px4.md", "swarmd px4 mavlink-signing key v1"): "the HKDF salt, a string",
}


@dataclass(frozen=True)
class DocCommand:
    """One command line as a doc shows it, with where it is."""

    doc: str
    line: int
    text: str  # the span or block line as written (continuations joined)
    argv: tuple[str, ...]  # program first, placeholders substituted
    partial: bool  # a mention or an elision: required arguments are not checked

    def where(self) -> str:
        return f"{self.doc}:{self.line}: `{self.text}`"


# -- extraction ---------------------------------------------------------------------------

_FENCE = re.compile(r"^\s*(`{3,}|~{3,})\s*([\w+-]*)")
_INLINE = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.DOTALL)
_ANGLE = re.compile(r"<([A-Za-z][\w-]*)>")


def _snippets(doc: str) -> Iterator[tuple[int, str, bool]]:
    """(line number, text, from a code block) for every shell line and inline code span."""
    lines = (ROOT / doc).read_text(encoding="utf-8").splitlines()
    prose: list[str] = []  # the doc with its blocks blanked, so offsets keep their lines
    i = 0
    while i < len(lines):
        fence = _FENCE.match(lines[i])
        if not fence:
            prose.append(lines[i])
            i += 1
            continue
        start, lang, body = i, fence.group(2).lower(), []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence.group(1)):
            body.append((i + 1, lines[i]))
            i += 1
        i += 1
        prose.extend([""] * (i - start))
        if lang not in NOT_SHELL:
            yield from _block_lines(body)
    text = "\n".join(prose)
    for m in _INLINE.finditer(text):
        span = m.group(2).replace("\n", " ").strip()
        yield text.count("\n", 0, m.start()) + 1, span.replace("\\|", "|"), False


def _block_lines(body: list[tuple[int, str]]) -> Iterator[tuple[int, str, bool]]:
    prompted = any(line.lstrip().startswith("$ ") for _, line in body)
    joined: list[tuple[int, str]] = []
    carry: tuple[int, str] | None = None
    for number, line in body:
        if carry is not None:
            number, line = carry[0], carry[1] + " " + line.strip()
        if line.rstrip().endswith("\\"):
            carry = (number, line.rstrip()[:-1].rstrip())
            continue
        carry = None
        joined.append((number, line))
    for number, line in joined:
        stripped = line.strip()
        if prompted:
            if not stripped.startswith("$ "):
                continue  # output under a prompt
            stripped = stripped[2:]
        yield number, stripped, True


def _tokens(text: str) -> list[str]:
    lexer = shlex.shlex(_ANGLE.sub(r"\1", text), posix=True, punctuation_chars="|;&<>")
    lexer.commenters = "#"
    lexer.whitespace_split = True
    return list(lexer)


def _segments(tokens: list[str]) -> Iterator[list[str]]:
    """The simple commands of a shell line: split at ; && || & and pipes, redirections out."""
    seg: list[str] = []
    skip_next = False
    for tok in tokens:
        if skip_next:
            skip_next = False
            continue
        if tok and set(tok) <= set("<>&") and tok not in ("&", "&&"):
            skip_next = True  # a redirection and its file
            continue
        if tok in (";", "&&", "||", "&"):
            yield seg
            seg = []
            continue
        seg.append(tok)
    yield seg


def _alternatives(seg: list[str]) -> list[list[str]]:
    """``a b | c | d e`` (a synopsis) -> [a b e], [a c e], [a d e]; a real pipe ends it."""
    pieces: list[list[str]] = [[]]
    for tok in seg:
        if tok == "|":
            pieces.append([])
        else:
            pieces[-1].append(tok)
    head = pieces[0]
    alts = [head[-1:]]
    tail: list[str] = []
    for piece in pieces[1:]:
        if not piece or piece[0] in PIPE_READERS or not head:
            break
        alts.append(piece[:1])
        tail = piece[1:]
    if len(alts) == 1:
        return [head]
    return [head[:-1] + alt + tail for alt in alts]


def _strip_prefix(seg: list[str]) -> list[str]:
    """Drop ``sudo``, ``ssh [-o X] HOST``, ``VAR=value`` and a ``for`` in front."""
    i = 0
    while i < len(seg):
        word = seg[i]
        if word in PREFIX_WORDS or re.fullmatch(r"[A-Za-z_]\w*=\S*", word):
            i += 1
        elif word == "ssh":
            i += 1
            while i < len(seg) and seg[i].startswith("-"):
                i += 2 if seg[i] in ("-o", "-p", "-i", "-l", "-J", "-F") else 1
            i += 1  # the host
        else:
            break
    return seg[i:]


def _substitute(word: str) -> str:
    word = word.strip("[]")
    if word.endswith("...") and word != "...":
        word = word[:-3]
    return NUMBER_PLACEHOLDERS.get(word, word)


def doc_commands(doc: str) -> Iterator[DocCommand]:
    """Every swarmd/swarmctl command line in ``doc`` (module docstring: the rules)."""
    for number, text, _block in _snippets(doc):
        if not re.search(r"\b(swarmd|swarmctl)\b", text):
            continue
        if any(d == doc and t in text for d, t in SKIPPED):
            continue
        try:
            tokens = _tokens(text)
        except ValueError:
            continue  # not shell (an unbalanced quote in prose); no command starts it
        for seg in _segments(tokens):
            for alt in _alternatives(seg):
                words = _strip_prefix(alt)
                if not words or words[0].rsplit("/", 1)[-1] not in PROGRAMS:
                    continue
                program = words[0].rsplit("/", 1)[-1]
                args = [_substitute(w) for w in words[1:] if w.strip("[]")]
                # `--sign-key ...`: the option's value; `key ... --out`: an elision
                args = [
                    "VALUE" if a == "..." and i and args[i - 1].startswith("-") else a
                    for i, a in enumerate(args)
                ]
                elided = "..." in args
                argv = (program, *(a for a in args if a != "..."))
                yield DocCommand(doc, number, text, argv, elided or _is_mention(argv))


def _subcommand_path(argv: tuple[str, ...]) -> tuple[str, ...]:
    """The program and the subcommand words ``argv`` starts with."""
    parser = PROGRAMS[argv[0]]()
    path: tuple[str, ...] = (argv[0],)
    for word in argv[1:]:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            break
        parser = subs[0].choices[word]
        path = (*path, word)
    return path


def _is_mention(argv: tuple[str, ...]) -> bool:
    """``swarmd run``: only the program and its subcommands, the way prose names them."""
    return len(_subcommand_path(argv)) == len(argv)


# -- parsing ------------------------------------------------------------------------------


class DocParseError(Exception):
    """The parser refused a doc line (its message)."""


def _parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def _prepare(parser: argparse.ArgumentParser, partial: bool) -> argparse.ArgumentParser:
    """Full option names only; for a mention or elision, nothing required."""
    for p in _parsers(parser):
        p.allow_abbrev = False
        if partial:
            for action in p._actions:
                action.required = False
                if not action.option_strings and action.nargs is None:
                    action.nargs = "?"
            for group in p._mutually_exclusive_groups:
                group.required = False
    return parser


def parse(cmd: DocCommand, monkeypatch: pytest.MonkeyPatch) -> argparse.ArgumentParser:
    """Parse ``cmd`` with its program's parser (nothing runs); the parser it reached."""

    def error(self: argparse.ArgumentParser, message: str) -> None:
        raise DocParseError(f"{self.prog}: {message}")

    monkeypatch.setattr(argparse.ArgumentParser, "error", error)
    parser = _prepare(PROGRAMS[cmd.argv[0]](), cmd.partial)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            parser.parse_args(list(cmd.argv[1:]))
        except SystemExit as exc:  # --version, --help: parsed, and they exit 0
            if exc.code not in (0, None):
                raise DocParseError(out.getvalue().strip()) from None
    return parser


ALL_COMMANDS: Final = [c for doc in DOCS for c in doc_commands(doc)]


def test_the_docs_show_commands() -> None:
    """The extraction finds the lines (a broken extractor would pass every check)."""
    docs = {c.doc for c in ALL_COMMANDS}
    assert docs == set(DOCS)
    assert len(ALL_COMMANDS) > 100


def test_every_skip_still_matches_a_doc_line() -> None:
    """A listed skip whose line is gone would hide the next line that matches it."""
    stale = [key for key in SKIPPED if not any(key[1] in text for _, text, _ in _snippets(key[0]))]
    assert not stale, f"SKIPPED entries that match no doc line: {stale}"


def test_every_doc_command_parses(monkeypatch: pytest.MonkeyPatch) -> None:
    failures = []
    for cmd in ALL_COMMANDS:
        try:
            parse(cmd, monkeypatch)
        except DocParseError as exc:
            failures.append(f"{cmd.where()}\n    {' '.join(cmd.argv)}\n    -> {exc}")
    assert not failures, f"{len(failures)} doc command lines do not parse:\n" + "\n".join(failures)


# -- operations.md covers every subcommand, option and exit code ---------------------------


def _options_used(argv: tuple[str, ...]) -> set[tuple[tuple[str, ...], str]]:
    """(subcommand path, action dest) for the path and every option ``argv`` uses."""
    parser = PROGRAMS[argv[0]]()
    path: tuple[str, ...] = (argv[0],)
    used = {(path, "")}
    for word in argv[1:]:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if subs and word in subs[0].choices:
            parser = subs[0].choices[word]
            path = (*path, word)
            used.add((path, ""))
            continue
        action = parser._option_string_actions.get(word.split("=", 1)[0])
        if action is not None:
            used.add((path, action.dest))
    return used


def _every_option() -> Iterator[tuple[tuple[str, ...], str, str]]:
    """(subcommand path, dest, how --help shows it) for every subcommand and option."""

    def walk(
        parser: argparse.ArgumentParser, path: tuple[str, ...]
    ) -> Iterator[tuple[tuple[str, ...], str, str]]:
        yield path, "", " ".join(path)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk(sub, (*path, name))
            elif action.option_strings and not isinstance(action, argparse._HelpAction):
                yield path, action.dest, f"{' '.join(path)} {'/'.join(action.option_strings)}"

    for program, build in PROGRAMS.items():
        yield from walk(build(), (program,))


def test_operations_md_names_every_subcommand_and_option() -> None:
    used = set().union(*(_options_used(c.argv) for c in ALL_COMMANDS if c.doc == OPERATIONS))
    missing = [shown for path, dest, shown in _every_option() if (path, dest) not in used]
    assert not missing, f"{OPERATIONS} shows no command line with: " + ", ".join(missing)


def _documented_exit_codes() -> dict[str, set[int]]:
    """The codes each program's CLI modules name: "Exit codes ..." paragraphs of their
    docstrings and "exit N" in them or in a help text."""
    found: dict[str, set[int]] = {"swarmd": set(), "swarmctl": set()}
    cli = ROOT / "swarmd" / "cli"
    daemon_main = (cli / "swarmd_main.py").read_text(encoding="utf-8")
    for source in sorted(cli.glob("*.py")):
        # a module swarmd_main registers (local-firewall) is a swarmd subcommand
        ours = source.name == "swarmd_main.py" or f"import {source.stem}" in daemon_main
        program = "swarmd" if ours else "swarmctl"
        text = source.read_text(encoding="utf-8")
        for para in re.split(r"\n\s*\n", text):
            if re.search(r"\bExit codes\b", para):
                body = para[para.index("Exit codes") :]
                found[program] |= {int(n) for n in re.findall(r"(?:^|[:;,(]\s*)(\d{1,3}) ", body)}
        found[program] |= {int(n) for n in re.findall(r"\bexit (\d{1,3})\b", text, re.I)}
    return found


def _exit_table() -> dict[int, tuple[str, str]]:
    """operations.md's exit-code table: code -> (swarmd column, swarmctl column)."""
    text = (ROOT / OPERATIONS).read_text(encoding="utf-8")
    section = text.split("## Exit codes", 1)[1].split("\n## ", 1)[0]
    rows: dict[int, tuple[str, str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if len(cells) == 3 and cells[0].isdigit():
            rows[int(cells[0])] = (cells[1], cells[2])
    return rows


def test_every_documented_exit_code_is_in_the_table() -> None:
    table = _exit_table()
    documented = _documented_exit_codes()
    named = {v for k, v in vars(exitcodes).items() if k.startswith("EX_") and isinstance(v, int)}
    assert documented["swarmd"] and documented["swarmctl"]
    missing = []
    for column, program in enumerate(("swarmd", "swarmctl")):
        for code in sorted(documented[program]):
            if not table.get(code, ("", ""))[column]:
                missing.append(f"{code} ({program})")
    missing += [f"{code} (swarmd/exitcodes.py)" for code in sorted(named - set(table))]
    assert not missing, f"{OPERATIONS}'s exit-code table lacks: " + ", ".join(missing)
