"""``swarmd check-config``'s judgement of the unit's sandbox: does every folder the daemon
writes lie where the unit lets it write?

``swarmd run`` under the shipped unit (systemd/swarmd.service: ``ProtectSystem=strict``,
``ProtectHome=yes``, ``PrivateTmp=yes``) may write only below ``StateDirectory=`` and
``RuntimeDirectory=`` (/var/lib/swarmd, /run/swarmd). ``check-config`` runs outside that
sandbox, so a config naming a folder elsewhere passed it and stopped ``run`` (exit 73 for
the state folders, 69 for the control socket's). Now the check reads the unit the daemon
will run under (``find_unit``) and refuses each written folder outside it
(``refuse_outside``) with ``run``'s one-line style: file, line, field, problem, fix.

Which unit: ``--unit PATH`` (that file and its ``PATH.d/*.conf`` drop-ins), else the
installed one (``systemctl cat swarmd.service``: the unit and its drop-ins as systemd
merged them), else the first ``swarmd.service`` in systemd's unit folders with its
drop-ins. None found (a lab, a bench): the ``ok`` line says the sandbox was not judged.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.config import DaemonConfig
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_UNAVAILABLE, EX_USAGE, StartupError
from swarmd.unitsandbox import Assignment, Sandbox, UnitSyntaxError, parse_unit

UNIT_NAME: Final = "swarmd.service"
# systemd.unit(5), "System Unit Search Path", highest priority first
UNIT_DIRS: Final = (
    "/etc/systemd/system",
    "/run/systemd/system",
    "/usr/local/lib/systemd/system",
    "/usr/lib/systemd/system",
    "/lib/systemd/system",
)
SYSTEMCTL_TIMEOUT_S: Final = 10.0


@dataclass(frozen=True, slots=True)
class Unit:
    """A unit's text (with its drop-ins appended, as ``systemctl cat`` shows them: each
    file after a ``# PATH`` line) and where it came from, for the operator; ``files``: the
    first line of each file's text in ``text``, and its path."""

    source: str
    text: str
    files: tuple[tuple[int, str], ...] = ()

    def file_of(self, line: int) -> tuple[str, int]:
        """The file that holds ``line`` of ``text`` and its line number there."""
        found = [(first, path) for first, path in self.files if first <= line]
        if not found:
            return self.source, line
        first, path = found[-1]
        return path, line - first + 1

    def where(self, line: int) -> str:
        """``line`` of ``text`` for the operator: ``FILE:LINE``."""
        path, number = self.file_of(line)
        return f"{path}:{number}"


# systemctl cat: "# PATH" before each file (the unit, then its drop-ins)
_CAT_HEADER: Final = re.compile(r"# (/\S+\.(?:service|conf))")


def _cat_files(text: str) -> tuple[tuple[int, str], ...]:
    """The files of ``systemctl cat``'s output, by its ``# PATH`` lines (the first line, or
    one after a blank line, naming a .service or .conf file)."""
    lines = text.splitlines()
    out: list[tuple[int, str]] = []
    for number, line in enumerate(lines, 1):
        header = _CAT_HEADER.fullmatch(line)
        if header and (number == 1 or not lines[number - 2].strip()):
            out.append((number + 1, header.group(1)))
    return tuple(out)


def _with_dropins(path: Path, dropin_dirs: list[Path]) -> tuple[str, tuple[tuple[int, str], ...]]:
    """The unit file's text, then its drop-ins' (``*.conf``, by file name; a name in an
    earlier folder hides the same name in a later one: systemd.unit(5)), as ``systemctl
    cat`` shows them, and where each file starts."""
    chosen: dict[str, Path] = {}
    for folder in dropin_dirs:
        if folder.is_dir():
            for conf in folder.glob("*.conf"):
                chosen.setdefault(conf.name, conf)
    parts: list[str] = []
    files: list[tuple[int, str]] = []
    line = 1
    for file in [path, *(chosen[name] for name in sorted(chosen))]:
        text = file.read_text("utf-8")
        text = text if text.endswith("\n") else text + "\n"
        files.append((line + 1, str(file)))
        parts.append(f"# {file}\n{text}")
        line += 1 + len(text.splitlines())
    return "".join(parts), tuple(files)


def find_unit(
    path: str | None, unit_dirs: tuple[str, ...] = UNIT_DIRS, *, systemctl: bool = True
) -> Unit | None:
    """The unit ``run`` will run under (see the module docstring); None if none is found.
    Raises ``OSError``/``UnicodeDecodeError`` for a ``--unit`` file that cannot be read."""
    if path is not None:
        unit = Path(path)
        return Unit(str(unit), *_with_dropins(unit, [Path(f"{unit}.d")]))
    program = shutil.which("systemctl") if systemctl else None
    if program is not None:
        try:
            done = subprocess.run(  # noqa: S603 - a fixed argv, no shell
                [program, "cat", "--no-pager", UNIT_NAME],
                capture_output=True,
                text=True,
                timeout=SYSTEMCTL_TIMEOUT_S,
                check=False,
            )
        except (OSError, subprocess.TimeoutExpired):
            done = None
        if done is not None and done.returncode == 0 and done.stdout.strip():
            return Unit(f"systemctl cat {UNIT_NAME}", done.stdout, _cat_files(done.stdout))
    for folder in unit_dirs:
        candidate = Path(folder) / UNIT_NAME
        if candidate.is_file():
            dropins = [Path(d) / f"{UNIT_NAME}.d" for d in unit_dirs]
            return Unit(str(candidate), *_with_dropins(candidate, dropins))
    return None


def written_folders(config: DaemonConfig) -> list[tuple[str, str, int]]:
    """(config field, folder, ``run``'s exit code when it cannot write there) for each
    folder the daemon writes in: node.key's (the boot epoch, the replay windows, the
    bundle floor, an XRCE agent's key), the data plane's state folder, the control
    socket's folder. The daemon writes no log file (stderr: the journal)."""
    key_field = "bundle.node_key" if config.bundle.node_key is not None else "bundle.path"
    out = [(key_field, config.bundle.node_state_dir, EX_CANTCREAT)]
    if config.dataplane.enabled:
        out.append(("dataplane.state_dir", config.dataplane.state_dir, EX_CANTCREAT))
    out.append(("control.socket", os.path.dirname(config.control_socket), EX_UNAVAILABLE))
    return out


def assignments(unit: Unit) -> list[Assignment]:
    """The unit's assignments (``parse_unit``); a unit that does not parse is refused
    (``StartupError``, 78) as the config's problem."""
    try:
        return parse_unit(unit.text)
    except UnitSyntaxError as exc:
        path, line = unit.file_of(exc.line)
        raise StartupError(
            f"unit {path}: line {line}: {exc.problem}; fix: correct the unit, or name "
            "another with --unit",
            EX_CONFIG,
        ) from None


def refuse_outside(config: DaemonConfig, unit: Unit) -> None:
    """Raise ``StartupError`` (``run``'s exit code, one line naming the config file, the
    field, why and the fix) for the first written folder the unit's sandbox does not let
    the daemon write; a unit that does not parse is refused as the config's problem."""
    sandbox = Sandbox.of(assignments(unit), os.path.exists)
    for field, folder, code in written_folders(config):
        # systemd resolves symlinks in its paths; the folder is judged where it leads
        real = os.path.realpath(os.path.abspath(folder))
        why = sandbox.why_not_writable(real)
        if why is None:
            continue
        shown = folder if real == os.path.abspath(folder) else f"{folder} (= {real})"
        if why.startswith("PrivateTmp"):
            # writable, but not this folder: the daemon would neither find what is here
            # nor keep what it writes (the executed ids: exactly once) past a restart
            outcome = "swarmd run would not see what is on disk here"
            fix = f"point {field} out of /tmp and /var/tmp"
        elif why.startswith(("ProtectHome=yes", "ProtectHome=tmpfs", "it is under Inacc")):
            outcome = f"swarmd run stops with exit {code}"
            fix = f"point {field} below one of those (no ReadWritePaths= reaches into it)"
        else:
            outcome = f"swarmd run stops with exit {code}"
            fix = (
                f"point {field} below one of those, or let the unit write it (a drop-in: "
                f"systemctl edit swarmd, [Service] ReadWritePaths={real})"
            )
        error = config.error(
            field,
            f"{shown} cannot be written by the daemon under {unit.source}: {why} "
            f"(writable there: {sandbox.writable_text()}); {outcome}",
            fix,
        )
        raise StartupError(str(error), code)


def load_unit(unit_path: str | None) -> Unit | None:
    """``find_unit``, a ``--unit`` file that cannot be read refused (``StartupError``, 64)."""
    try:
        return find_unit(unit_path)
    except (OSError, UnicodeDecodeError) as exc:
        raise StartupError(
            f"--unit {unit_path}: cannot read it ({exc}); fix: name the unit file swarmd "
            "runs under",
            EX_USAGE,
        ) from None


def sandbox_note(config: DaemonConfig, unit: Unit | None) -> str:
    """``check-config``'s judgement: refuses (``StartupError``) or returns what the ``ok``
    line says about the sandbox."""
    if unit is None:
        return f"no {UNIT_NAME} found (systemctl cat, {UNIT_DIRS[0]}, ...): sandbox not judged"
    refuse_outside(config, unit)
    return f"written folders judged under {unit.source}"
