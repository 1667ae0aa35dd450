"""YAML documents that answer bad input with one line: ``FILE:LINE: field F: problem; fix: ...``.

Shared by the mission checker (``swarmd.bundle.mission``) and the daemon config
(``swarmd.config``): both compose the node tree, so every value keeps the line it came from.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Final

import yaml

# libyaml's loader when PyYAML was built with it (10x faster on a 500-drone mission); both
# keep line marks on every node
Loader: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Hostile or broken files are refused with one line, before they can hurt the process:
# a mission of 1,000 drones is well under 1 MiB, a config a few KiB.
MAX_FILE_BYTES: Final = 16 * 1024 * 1024
# libyaml's composer recurses on the C stack once per nesting level: ~50,000 levels of
# "[" crash the interpreter (SIGSEGV, no exception), the pure-Python one raises
# RecursionError. Neither document format nests deeper than 6; 64 is generous.
MAX_DEPTH: Final = 64
_OPEN = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_CLOSE = (yaml.SequenceEndEvent, yaml.MappingEndEvent)


def unknown_field(key: object, allowed: tuple[str, ...]) -> tuple[str, str]:
    """The problem and the fix for a key its section does not know, worded once for the
    mission and the config."""
    return (
        f"unknown field {key!r}",
        f"remove it or correct the spelling; known fields: {', '.join(allowed)}",
    )


class FieldError(ValueError):
    """Bad input; ``str()`` is one line naming file, line, field, problem and fix."""

    def __init__(self, file: str, line: int | None, field: str, problem: str, fix: str) -> None:
        self.file = file
        self.line = line
        self.field = field
        self.problem = problem
        self.fix = fix
        super().__init__(str(self))

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line is not None else self.file
        # a message naming user input may carry newlines (a YAML scalar, a path): fold them,
        # the promise is one line
        return " ".join(f"{where}: field {self.field}: {self.problem}; fix: {self.fix}".split())


def read_text(
    path: str | Path, error: type[FieldError], *, missing_fix: str, what: str = "file"
) -> str:
    """The file's text, or ``error`` saying why it cannot be read."""
    return _read(path, error, missing_fix=missing_fix, what=what, regular=False)[0]


def read_regular_text(
    path: str | Path, error: type[FieldError], *, missing_fix: str, what: str = "file"
) -> tuple[str, os.stat_result]:
    """``read_text`` of a regular file only, opened ``O_NONBLOCK`` (a FIFO never holds the
    reader), and the ``fstat`` of what was read: the daemon's config, judged afterwards
    on this very file (``DaemonConfig.check_trusted_files``), not on whatever its path
    names by then (docs/security.md, the local user)."""
    return _read(path, error, missing_fix=missing_fix, what=what, regular=True)


def _read(
    path: str | Path, error: type[FieldError], *, missing_fix: str, what: str, regular: bool
) -> tuple[str, os.stat_result]:
    file = str(path)
    flags = os.O_RDONLY | os.O_CLOEXEC | (os.O_NONBLOCK if regular else 0)
    try:
        fd = os.open(path, flags)
        with open(fd, "rb") as f:
            info = os.fstat(fd)
            if regular and not stat.S_ISREG(info.st_mode):
                raise OSError(errno.EINVAL, "not a regular file")
            raw = f.read(MAX_FILE_BYTES + 1)  # bounded: a path may name /dev/zero
        if len(raw) > MAX_FILE_BYTES:
            raise error(
                file,
                None,
                "-",
                f"{what} larger than {MAX_FILE_BYTES // (1024 * 1024)} MiB",
                "give the right file",
            )
        return raw.decode("utf-8"), info
    except FileNotFoundError:
        raise error(file, None, "-", f"{what} not found", missing_fix) from None
    except UnicodeDecodeError as exc:
        raise error(file, None, "-", f"not UTF-8 text ({exc.reason})", "save it as UTF-8") from None
    except OSError as exc:
        raise error(
            file, None, "-", f"cannot read: {exc.strerror}", "check the path and permissions"
        ) from None


@contextmanager
def composed(
    text: str, file: str, error: type[FieldError], *, empty_fix: str
) -> Iterator[tuple[yaml.Node, yaml.SafeLoader]]:
    """The document's root node (with line marks) and its loader, disposed on exit."""
    loader = Loader(text)
    try:
        try:
            deepest, line = _depth(text)
            if deepest > MAX_DEPTH:
                raise error(
                    file,
                    line,
                    "<yaml>",
                    f"nested deeper than {MAX_DEPTH} levels",
                    "this is not a swarmd document; give the right file",
                )
            root = loader.get_single_node()
        except yaml.MarkedYAMLError as exc:
            mark = exc.problem_mark or exc.context_mark
            raise error(
                file,
                mark.line + 1 if mark is not None else None,
                "<yaml>",
                f"malformed YAML: {exc.problem or exc.context or 'unreadable'}",
                "correct the YAML syntax at this line (indentation, ':' after keys, quotes)",
            ) from None
        except yaml.YAMLError as exc:
            raise error(
                file, None, "<yaml>", f"malformed YAML: {exc}", "correct the YAML syntax"
            ) from None
        if root is None:
            raise error(file, 1, "<document>", "the file is empty", empty_fix)
        yield root, loader
    finally:
        loader.dispose()


def _depth(text: str) -> tuple[int, int]:
    """(deepest nesting, its line): the parser's events are a flat stream, no recursion."""
    depth = deepest = line = 0
    for event in yaml.parse(text, Loader=Loader):
        if isinstance(event, _OPEN):
            depth += 1
            if depth > deepest:
                mark = event.start_mark
                deepest, line = depth, (mark.line + 1 if mark is not None else 0)
                if deepest > MAX_DEPTH:
                    break  # no need to read the rest of a hostile file
        elif isinstance(event, _CLOSE):
            depth -= 1
    return deepest, line
