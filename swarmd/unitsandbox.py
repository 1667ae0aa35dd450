"""Where a systemd service may write: its unit file read, its file-system sandbox judged.

``swarmd check-config`` runs outside the sandbox the daemon runs in. The shipped unit
(systemd/swarmd.service) has ``ProtectSystem=strict``: every mount is read-only for the
daemon except ``StateDirectory=swarmd`` (/var/lib/swarmd) and ``RuntimeDirectory=swarmd``
(/run/swarmd). A config whose ``dataplane.state_dir`` lay elsewhere passed the check and
stopped ``swarmd run`` with exit 73 ("on a read-only mount"). So the check reads the unit
and asks this module, for each path the daemon writes, whether the sandbox lets it.

Two parts, both text in, values out (no file is read here; ``swarmd.cli.sandbox_check``
finds and reads the unit):

- ``parse_unit``: a small reader of systemd's documented syntax (systemd.syntax(7),
  systemd.unit(5)): ``[Section]`` headers, ``Key=value`` (blanks around ``=`` ignored),
  ``#``/``;`` comment lines, a trailing backslash continues the line (replaced by a space,
  comment lines between ignored). Every assignment is kept in order; what it means is the
  setting's to say (``Sandbox.of``).
- ``Sandbox.of`` reads the settings that decide writing (systemd.exec(5), "Sandboxing"):
  ``ProtectSystem=`` (``yes``: /usr, /boot, /efi read-only; ``full``: /etc too;
  ``strict``: everything but /dev, /proc, /sys), ``ProtectHome=`` (``yes``: /home, /root,
  /run/user inaccessible; ``read-only``; ``tmpfs``: an empty read-only tmpfs),
  ``PrivateTmp=`` (a private /tmp and /var/tmp, emptied when the service stops),
  ``ReadWritePaths=``, ``ReadOnlyPaths=``, ``InaccessiblePaths=`` (and their old names
  ``*Directories=``: lists, later assignments add, an empty one resets; a path prefixed
  ``-`` is ignored when it does not exist, ``+`` is relative to ``RootDirectory=``, here
  the host's root), ``StateDirectory=``, ``RuntimeDirectory=``, ``CacheDirectory=``,
  ``LogsDirectory=`` (writable under ``ProtectSystem=``: "also exclude the specific
  directories from the effect of ProtectSystem="), and ``DynamicUser=`` (implies
  ``ProtectSystem=strict``, ``ProtectHome=read-only`` and ``PrivateTmp=``). A single-value
  setting's later assignment wins.

- ``UnitIdentity.of`` reads whom the service runs as (systemd.exec(5), "Credentials"):
  ``User=``, ``Group=``, ``SupplementaryGroups=``, ``DynamicUser=``, and the folders
  systemd gives that user at each start (``swarmd.cli.unit_user`` resolves the names on
  the host).

Not read, and judged as if absent: ``BindPaths=``, ``TemporaryFileSystem=``,
``RootDirectory=``/``RootImage=``, mount units and a read-only superblock (the folder's
own mount is ``swarmd.bundle.statedir``'s). Where systemd's outcome is not plain (one path
both read-write and read-only), the judgement says "not writable": ``check-config`` then
refuses a config ``run`` might have started with, never the other way round.
"""

from __future__ import annotations

import posixpath
import shlex
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Final

# systemd.exec(5), Table 2: the directory settings and the folder their names are below
DIRECTORY_ROOTS: Final = {
    "StateDirectory": "/var/lib",
    "RuntimeDirectory": "/run",
    "CacheDirectory": "/var/cache",
    "LogsDirectory": "/var/log",
}
# what ProtectSystem=yes and full make read-only; strict: "/" (systemd.exec(5))
PROTECT_SYSTEM: Final = {
    "yes": ("/usr", "/boot", "/efi"),
    "full": ("/usr", "/boot", "/efi", "/etc"),
    "strict": ("/",),
}
API_TREES: Final = ("/dev", "/proc", "/sys")  # left writable by ProtectSystem=strict
HOME_TREES: Final = ("/home", "/root", "/run/user")  # ProtectHome=
# PrivateTmp=
TMP_TREES: Final = ("/tmp", "/var/tmp")  # noqa: S108 - names to judge, never written

# systemd.unit(5), "Specifiers": the ones a path setting of a system unit uses
SPECIFIERS: Final = {
    "S": "/var/lib",
    "t": "/run",
    "C": "/var/cache",
    "L": "/var/log",
    "E": "/etc",
    "T": "/tmp",  # noqa: S108 - a name to judge, never written
    "V": "/var/tmp",  # noqa: S108 - the same
    "%": "%",
}
# systemd.exec(5): the names before v231 mean the same lists
PATH_LISTS: Final = {
    "ReadWritePaths": "ReadWritePaths",
    "ReadWriteDirectories": "ReadWritePaths",
    "ReadOnlyPaths": "ReadOnlyPaths",
    "ReadOnlyDirectories": "ReadOnlyPaths",
    "InaccessiblePaths": "InaccessiblePaths",
    "InaccessibleDirectories": "InaccessiblePaths",
}
TRUE: Final = frozenset({"1", "yes", "y", "true", "t", "on"})  # systemd's parse_boolean


class UnitSyntaxError(ValueError):
    """A unit file line that is neither a section, an assignment nor a comment; ``line``:
    its number in the text parsed."""

    def __init__(self, line: int, problem: str) -> None:
        super().__init__(f"line {line}: {problem}")
        self.line = line
        self.problem = problem


# (section, key, value, line number), in file order
Assignment = tuple[str, str, str, int]


def parse_unit(text: str) -> list[Assignment]:
    """Every ``Key=value`` of ``text`` with its section and line, in order (see above).
    Raises ``UnitSyntaxError`` naming the line of anything else."""
    out: list[Assignment] = []
    section = ""
    pending = ""
    start = 0
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if pending and line[:1] in ("#", ";"):
            continue  # systemd.syntax(7): comment lines inside a continuation are dropped
        if not pending:
            if not line or line[0] in "#;":
                continue
            start = number
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        line, pending = pending + line, ""
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
            continue
        key, eq, value = line.partition("=")
        if not eq or not key.strip():
            raise UnitSyntaxError(start, "not a [Section], Key=value or comment")
        out.append((section, key.strip(), value.strip(), start))
    if pending:
        key, _, value = pending.partition("=")
        out.append((section, key.strip(), value.strip(), start))
    return out


def _expand(word: str) -> str:
    """``word`` with the specifiers of ``SPECIFIERS`` replaced (others kept as written)."""
    out: list[str] = []
    i = 0
    while i < len(word):
        if word[i] == "%" and i + 1 < len(word) and word[i + 1] in SPECIFIERS:
            out.append(SPECIFIERS[word[i + 1]])
            i += 2
        else:
            out.append(word[i])
            i += 1
    return "".join(out)


def _words(value: str) -> list[str]:
    """A space-separated list, quotes allowed (systemd's extract_first_word with unquoting);
    an unbalanced quote: split on blanks."""
    try:
        return shlex.split(value, comments=False, posix=True)
    except ValueError:
        return value.split()


def _norm(path: str) -> str:
    return posixpath.normpath("/" + path.lstrip("/")) if path else "/"


def under(path: str, tree: str) -> bool:
    """``path`` is ``tree`` or below it (both normalised, absolute)."""
    return tree == "/" or path == tree or path.startswith(tree.rstrip("/") + "/")


@dataclass(frozen=True, slots=True)
class Sandbox:
    """What a unit's ``[Service]`` section says about writing (see the module docstring).
    ``settings``: the lines that made it, for the operator (``ProtectSystem=strict``...)."""

    protect_system: str  # "no", "yes", "full", "strict"
    protect_home: str  # "no", "yes", "read-only", "tmpfs"
    private_tmp: bool
    read_write: tuple[str, ...]  # ReadWritePaths= and the directory settings' folders
    read_only: tuple[str, ...]
    inaccessible: tuple[str, ...]

    @classmethod
    def of(cls, assignments: Iterable[Assignment], exists: Callable[[str], bool]) -> Sandbox:
        """The sandbox of ``[Service]``'s assignments; ``exists``: whether a host path
        exists (a ``-`` path that does not is ignored, as systemd ignores it)."""
        single: dict[str, str] = {}
        lists: dict[str, list[str]] = {name: [] for name in set(PATH_LISTS.values())}
        directories: dict[str, list[str]] = {name: [] for name in DIRECTORY_ROOTS}
        for section, key, value, _line in assignments:
            if section != "Service":
                continue
            if key in PATH_LISTS:
                target = lists[PATH_LISTS[key]]
                if not value:
                    target.clear()  # "the specific list is reset"
                for word in _words(value):
                    path = _path_word(word, exists)
                    if path is not None:
                        target.append(path)
            elif key in DIRECTORY_ROOTS:
                _directory_assignment(directories[key], DIRECTORY_ROOTS[key], value)
            elif key in ("ProtectSystem", "ProtectHome", "PrivateTmp", "DynamicUser"):
                single[key] = value.lower()  # a later assignment wins
        dynamic = single.get("DynamicUser", "no") in TRUE
        system = _protect_system(single.get("ProtectSystem", "no"))
        home = _protect_home(single.get("ProtectHome", "no"))
        private_tmp = single.get("PrivateTmp", "no") in TRUE or single.get("PrivateTmp", "") in (
            "disconnected",
        )
        if dynamic:  # systemd.exec(5), DynamicUser=: these are implied
            system = "strict"
            home = home if home in ("yes", "tmpfs") else "read-only"
            private_tmp = True
        writable = [*lists["ReadWritePaths"], *(p for d in directories.values() for p in d)]
        if dynamic:
            writable += _private_twins(directories)
        return cls(
            system,
            home,
            private_tmp,
            tuple(writable),
            tuple(lists["ReadOnlyPaths"]),
            tuple(lists["InaccessiblePaths"]),
        )

    def why_not_writable(self, path: str) -> str | None:
        """Why the service could not create or write ``path`` (absolute, symlinks already
        resolved by the caller), or None. The most specific rule wins, as systemd orders
        its mounts by path; an inaccessible tree hides every rule below it (systemd.exec(5):
        "it is not possible to nest ReadWritePaths= ... inside it")."""
        path = _norm(path)
        for tree in self.inaccessible:
            if under(path, tree):
                return f"it is under InaccessiblePaths={tree}"
        if self.protect_home in ("yes", "tmpfs"):
            for tree in HOME_TREES:
                if under(path, tree):
                    what = "inaccessible" if self.protect_home == "yes" else "an empty tmpfs"
                    return f"ProtectHome={self.protect_home} makes {tree} {what}"
        if self.private_tmp:
            for tree in TMP_TREES:
                if under(path, tree):
                    return (
                        f"PrivateTmp=yes gives the service its own {tree}, emptied at each "
                        "stop and not seen by other processes (swarmctl, the next start)"
                    )
        # (length of the rule's tree, writable?, the rule) for each rule over the path
        rules: list[tuple[int, bool, str]] = []
        for tree in self.read_write:
            if under(path, tree):
                rules.append((len(tree), True, f"ReadWritePaths={tree}"))
        for tree in self.read_only:
            if under(path, tree):
                rules.append((len(tree), False, f"ReadOnlyPaths={tree}"))
        if self.protect_home == "read-only":
            rules += [
                (len(t), False, "ProtectHome=read-only") for t in HOME_TREES if under(path, t)
            ]
        for tree in PROTECT_SYSTEM.get(self.protect_system, ()):
            if under(path, tree):
                rules.append((len(tree) if tree != "/" else 0, False, self._system_rule(tree)))
        if self.protect_system == "strict":
            rules += [(len(t), True, f"{t} (an API tree)") for t in API_TREES if under(path, t)]
        if not rules:
            return None
        longest = max(length for length, _, _ in rules)
        # at one length, read-only beats read-write: when unsure, "not writable"
        winners = [r for r in rules if r[0] == longest]
        refusing = [r for r in winners if not r[1]]
        if refusing:
            return f"{refusing[0][2]} makes it read-only"
        return None

    def _system_rule(self, tree: str) -> str:
        if self.protect_system == "strict":
            return "ProtectSystem=strict"
        return f"ProtectSystem={self.protect_system} ({tree})"

    def writable_text(self) -> str:
        """The writable trees, for a refusal's line ("/var/lib/swarmd /run/swarmd")."""
        return " ".join(self.read_write) or "none"


def _directory_assignment(target: list[str], root: str, value: str) -> None:
    """One ``StateDirectory=``-style assignment added to ``target`` (an empty one resets
    it): each name becomes its folder below ``root``."""
    if not value:
        target.clear()
    for word in _words(value):
        # "name" or, since v257, "name:symlink": the folder is the name's
        name = _expand(word).split(":", 1)[0]
        target.append(_norm(root + "/" + name))


def _private_twins(directories: dict[str, list[str]]) -> list[str]:
    """Under ``DynamicUser=`` the state, cache and logs folders live below ``private/``
    with a symlink at the plain name (systemd.exec(5), ``StateDirectory=``): the folders a
    caller that resolved that symlink sees."""
    return [
        _norm(f"{DIRECTORY_ROOTS[key]}/private/{path[len(DIRECTORY_ROOTS[key]) + 1 :]}")
        for key in ("StateDirectory", "CacheDirectory", "LogsDirectory")
        for path in directories[key]
    ]


@dataclass(frozen=True, slots=True)
class Setting:
    """One name a unit's setting gave and the line (of the unit's text) that gave it."""

    value: str
    line: int


@dataclass(frozen=True, slots=True)
class UnitIdentity:
    """Whom a unit runs its service as (systemd.exec(5), "Credentials"): ``User=`` and
    ``Group=`` (a later assignment wins, an empty one resets it: root, or the user's own
    group), ``SupplementaryGroups=`` (lists add up, an empty one resets), ``DynamicUser=``
    (a user allocated at each start, unless a static user of that name exists), and the
    folders systemd creates and gives that user at each start (``StateDirectory=``,
    ``RuntimeDirectory=``, ``CacheDirectory=``, ``LogsDirectory=``: "the innermost
    specified directories will be owned by the user and group specified in User= and
    Group=", recursively when their owner differs; not ``ConfigurationDirectory=``)."""

    user: Setting | None
    group: Setting | None
    supplementary: tuple[Setting, ...]
    dynamic: Setting | None  # the DynamicUser= line that turned it on
    chowned: tuple[str, ...]

    @classmethod
    def of(cls, assignments: Iterable[Assignment]) -> UnitIdentity:
        """The identity of ``[Service]``'s assignments (see the class docstring)."""
        single: dict[str, Setting | None] = {"User": None, "Group": None, "DynamicUser": None}
        supplementary: list[Setting] = []
        directories: dict[str, list[str]] = {name: [] for name in DIRECTORY_ROOTS}
        for section, key, value, line in assignments:
            if section != "Service":
                continue
            if key in single:
                single[key] = Setting(_expand(value), line) if value else None
            elif key == "SupplementaryGroups":
                if not value:
                    supplementary.clear()  # "the list of supplementary groups is reset"
                supplementary += [Setting(_expand(word), line) for word in _words(value)]
            elif key in DIRECTORY_ROOTS:
                _directory_assignment(directories[key], DIRECTORY_ROOTS[key], value)
        dynamic = single["DynamicUser"]
        if dynamic is not None and dynamic.value.lower() not in TRUE:
            dynamic = None
        chowned = [path for paths in directories.values() for path in paths]
        if dynamic is not None:
            chowned += _private_twins(directories)
        return cls(single["User"], single["Group"], tuple(supplementary), dynamic, tuple(chowned))


def _path_word(word: str, exists: Callable[[str], bool]) -> str | None:
    """One path of a path list: ``-`` (ignored if missing) then ``+`` (relative to
    ``RootDirectory=``: the host's root here), specifiers expanded; None if ignored."""
    optional = word.startswith("-")
    word = word[1:] if optional else word
    word = word[1:] if word.startswith("+") else word
    path = _norm(_expand(word))
    if optional and not exists(path):
        return None
    return path


def _protect_system(value: str) -> str:
    if value in ("full", "strict"):
        return value
    return "yes" if value in TRUE else "no"


def _protect_home(value: str) -> str:
    if value in ("read-only", "tmpfs"):
        return value
    return "yes" if value in TRUE else "no"
