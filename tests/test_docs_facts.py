"""The numbers and names the operator docs state, read from the code that sets them.

A newcomer trusts a default the docs give ("``--timeout`` (default 60 s)", "the last 64
peer changes"); each was true when written, and the code moved on since in other places.
These checks read the value from the code (a parser's default, a named constant, the
config loader's field list) and look for the doc's sentence with that value in it, so a
change on either side fails here and names the doc and the fact.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Final

import pytest

from swarmd import config, control, peerlog, statefile, udp
from swarmd.auth import epoch, windows
from swarmd.bundle import floor
from swarmd.cli import firewall_cmd, status_cmd, swarmctl, swarmd_main
from swarmd.dataplane.types import CommandKind
from swarmd.px4 import xrce_key
from swarmd.px4.readiness import Reason
from swarmd.swarm import commander, issuer

ROOT: Final = Path(__file__).resolve().parent.parent
OPERATIONS: Final = "docs/operations.md"


def _doc(name: str) -> str:
    """The doc as one line of text: a sentence may wrap anywhere."""
    return " ".join((ROOT / name).read_text(encoding="utf-8").split())


def _subparser(parser: argparse.ArgumentParser, *path: str) -> argparse.ArgumentParser:
    for name in path:
        (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    return parser


def _default(parser: argparse.ArgumentParser, option: str) -> object:
    (action,) = (a for a in parser._actions if option in a.option_strings)
    return action.default


def _seconds(value: object) -> str:
    assert isinstance(value, float | int)
    return f"{value:g}"


def test_takeoff_and_land_wait_as_long_as_the_doc_says() -> None:
    text = _doc(OPERATIONS)
    ctl = swarmctl.build_parser()
    takeoff = _seconds(_default(_subparser(ctl, "takeoff"), "--timeout"))
    assert f"within `--timeout` (default {takeoff} s)" in text
    for kind in ("land", "hold", "abort"):
        wait = _seconds(_default(_subparser(ctl, kind), "--timeout"))
        assert f"swarmctl's {wait} s wait" in text, kind


def test_the_validity_table_is_the_issuers_defaults() -> None:
    text = _doc(OPERATIONS)
    rows = {
        "TAKEOFF": CommandKind.TAKEOFF,
        "HOLD": CommandKind.HOLD,
        "LAND, ABORT": CommandKind.LAND,
    }
    for label, kind in rows.items():
        valid = _seconds(issuer.DEFAULT_VALID_FOR_S[kind])
        assert f"| {label} | {valid} s |" in text, label
    most = _seconds(issuer.MAX_VALID_FOR_S)
    assert f"Up to {most} s may be given" in text
    assert f"a validity outside [0.001, {most}] s" in text
    land, abort = CommandKind.LAND, CommandKind.ABORT
    assert issuer.DEFAULT_VALID_FOR_S[land] == issuer.DEFAULT_VALID_FOR_S[abort]
    # the commander reports `unreachable` this long after a command's validity ended
    assert f"and, {_seconds(commander.UNREACHABLE_GRACE_S)} s later" in text


def test_watch_refreshes_as_often_as_the_doc_says() -> None:
    interval = _seconds(_default(_subparser(swarmctl.build_parser(), "watch"), "--interval"))
    assert f"every S seconds (default {interval})" in _doc(OPERATIONS)


@pytest.mark.parametrize(
    ("value", "sentence"),
    [
        (peerlog.MAX_PEER_CHANGES, "keeps the last {} peer changes"),
        (status_cmd.WATCH_LOG_LINES, "(the last {} on a terminal)"),
        (commander.MAX_TRACKED_COMMANDS, "(the last {}, `MAX_TRACKED_COMMANDS`"),
        (commander.MAX_DECIDED_COMMANDS, "the last {} over all lives, `MAX_DECIDED_COMMANDS`"),
        (control.MAX_LINE_BYTES // 1024, "capped at {} KiB per line"),
        (control.MAX_CLIENTS, "and {} concurrent clients"),
        (_seconds(control.REQUEST_DEADLINE_S), "each request line within {} s"),
        (_seconds(control.REQUEST_DEADLINE_S / 2), "`--interval` of {} s or more reconnects"),
    ],
)
def test_the_caps_the_doc_names_are_the_codes(value: object, sentence: str) -> None:
    assert sentence.format(value) in _doc(OPERATIONS)


def test_the_local_firewall_row_names_every_backend() -> None:
    """The command table's row of ``swarmd local-firewall`` lists the ``--backend`` choices
    its parser takes and the default, so a backend added to the code is added there too."""
    firewall = _subparser(swarmd_main.build_parser(), "local-firewall")
    (backend,) = (a for a in firewall._actions if "--backend" in a.option_strings)
    assert backend.choices is not None
    (row,) = (
        line
        for line in (ROOT / OPERATIONS).read_text(encoding="utf-8").splitlines()
        if line.startswith("| `swarmd local-firewall --config FILE")
    )
    assert f"`--backend` `{backend.default}` (the default" in row
    for choice in backend.choices:
        assert f"`{choice}`" in row, choice


def test_the_shipped_config_names_every_field_the_loader_takes() -> None:
    """config/swarmd.yaml is the operator's reference (docs/deploy.md installs it): every
    field the loader accepts is in it, set or as a commented example, so a newcomer who
    reads "set px4.loopback_user" finds where it goes."""
    shipped = (ROOT / "config" / "swarmd.yaml").read_text(encoding="utf-8")
    missing = []
    for section, fields in config._FIELDS.items():
        if section == "<top>":
            continue
        for field in fields:
            # `  field:` under its section, or `# field:` in a commented example
            if not re.search(rf"^[ \t]*#?[ \t]*{re.escape(field)}:", shipped, re.MULTILINE):
                missing.append(f"{section}.{field}")
    assert missing == []


def test_every_event_the_log_table_names_is_one_the_daemon_logs() -> None:
    """A renamed log event leaves a grep of the journal empty; each event the table of
    docs/operations.md ("Logs") names must be a string in the daemon's code."""
    table = re.findall(
        r"^\| `([a-z0-9_]+)`(?:, `([a-z0-9_]+)`)? \| (?:debug|info|warning|error) \|",
        (ROOT / OPERATIONS).read_text(encoding="utf-8"),
        re.MULTILINE,
    )
    events = {name for row in table for name in row if name}
    assert {"state_save_failed", "command_refused_memory_lost", "started"} <= events
    code = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "swarmd").rglob("*.py"))
    assert sorted(e for e in events if f'"{e}"' not in code) == []


@pytest.mark.parametrize(
    "name",
    [
        epoch.FILE_PATTERN,
        windows.FILE_PATTERN,
        floor.FILE_PREFIX + "{node}",
        statefile.FILE_PATTERN,
        xrce_key.XRCE_KEY_FILE,
    ],
)
def test_the_deploy_table_names_each_state_file_as_the_code_does(name: str) -> None:
    """docs/deploy.md's table of where things live: the files swarmd writes beside its
    node key and in its state dir, under the names the code gives them."""
    assert f"`/var/lib/swarmd/{name.format(node='<node>')}`" in _doc("docs/deploy.md")


def test_the_readiness_reasons_are_px4s_in_their_order() -> None:
    """operations.md's "Readiness reasons" lists a member's own reasons in the order they
    are checked (the first failing one is reported), as ``Reason`` does."""
    text = _doc(OPERATIONS)
    start = text.index("### Readiness reasons")
    section = text[start : text.index("or `px4_disabled`", start)]
    listed = re.findall(r"`([a-z0-9_]+)`(?: \(XRCE\))?[,)]", section)
    assert listed == [r.value for r in Reason]


def _leaves(parser: argparse.ArgumentParser, path: str = "") -> dict[str, set[str]]:
    """Each runnable subcommand ("bundle keygen") and its options."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {path: {o for a in parser._actions for o in a.option_strings}}
    found: dict[str, set[str]] = {}
    for name, sub in subs[0].choices.items():
        found |= _leaves(sub, f"{path} {name}".strip())
    return found


def test_the_readme_names_the_commands_without_json() -> None:
    text = _doc("README.md")
    start = text.index("machine-readable output with `--json` (every swarmctl command but")
    named = set(re.findall(r"`([a-z0-9 -]+)`", text[start : text.index(")", start)]))
    named.discard("--json")
    leaves = _leaves(swarmctl.build_parser())
    assert named == {cmd for cmd, options in leaves.items() if "--json" not in options}


def test_the_drone_wheels_deploy_names_are_the_runtime_lock() -> None:
    """docs/deploy.md, step 2, names what the locked download saved: the same packages
    and versions as requirements/runtime-aarch64.lock (``make lock`` moves both)."""
    lock = dict(
        re.findall(
            r"^([A-Za-z0-9._-]+)==(\S+)",
            (ROOT / "requirements" / "runtime-aarch64.lock").read_text(encoding="utf-8"),
            re.MULTILINE,
        )
    )
    text = _doc("docs/deploy.md")
    start = text.index("Run here (session 13) it saved")
    said = re.findall(
        r"([A-Za-z][\w-]*) (\d+\.\d+(?:\.\d+)?)", text[start : text.index("as pure Python.", start)]
    )
    assert {name.lower(): version for name, version in said} == lock


def test_deploys_buffer_and_lock_wait_are_the_codes() -> None:
    """The sysctl docs/deploy.md has the operator set is the SPDP socket's own request, and
    the xtables lock wait both docs state is the one ``swarmd local-firewall`` passes."""
    mib = udp.RECV_BUFFER_BYTES >> 20
    assert mib << 20 == udp.RECV_BUFFER_BYTES
    deploy = _doc("docs/deploy.md")
    assert f"the {mib} MiB receive buffer they ask for" in deploy
    assert f"net.core.rmem_max = {udp.RECV_BUFFER_BYTES}" in deploy
    wait = firewall_cmd.XT_LOCK_WAIT_S
    assert f"`--apply` waits up to {wait} s for the xtables lock" in _doc(OPERATIONS)
    assert f"passes `--wait={wait}`" in deploy


OPERATOR_DOCS: Final = (
    "README.md",
    "docs/preflight.md",
    "docs/deploy.md",
    "docs/operations.md",
    "docs/px4.md",
    "docs/ros2.md",
)


@pytest.mark.parametrize("doc", OPERATOR_DOCS)
def test_every_test_a_doc_cites_exists(doc: str) -> None:
    """The docs back a claim with "Output of tests/x.py::test_y": a renamed or removed test
    leaves the claim without its proof. Each cited file, and each cited test in it, exists;
    a bare `test_y` must be defined in some test file."""
    text = (ROOT / doc).read_text(encoding="utf-8")
    missing = []
    for path, name in re.findall(r"(tests/[a-z0-9_/]+\.py)(?:::(\w+))?", text):
        source = ROOT / path
        if not source.is_file():
            missing.append(path)
        elif name and not re.search(rf"def {name}\b", source.read_text(encoding="utf-8")):
            missing.append(f"{path}::{name}")
    tests = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "tests").glob("test_*.py"))
    for name in re.findall(r"`(test_\w+)`", text):
        if not re.search(rf"def {name}\b", tests):
            missing.append(name)
    assert missing == []
