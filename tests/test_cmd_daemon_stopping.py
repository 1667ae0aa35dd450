"""A command asked of a stopping daemon is "not reachable, nothing sent" (exit 2), not a
usage error (session 16).

While swarmd stops, its swarm core stops first and its control socket a moment later
(``Daemon.stop``: ``SwarmApp.stop`` closes the driver, then the control server closes). A
``takeoff`` or ``command`` request in that window ran nothing (``Driver.call``) and was
refused with ``the daemon is stopping``, a refusal like a bad altitude's, so swarmctl exited
64 (EX_USAGE) although the command line was fine and nothing was sent. The refusal now
carries ``code: stopping`` (swarmd/control.py) and swarmctl exits 2 with one line saying
nothing was sent (docs/operations.md, "Exit codes").

A real commander daemon on loopback whose swarm layer has stopped, a real control socket,
swarmctl's own ``main``.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from structlog.testing import capture_logs

from swarmd.cli import swarmctl
from swarmd.control import STOPPING, ControlServer, RequestInvalid
from swarmd.exitcodes import EX_FAILED, EX_UNREACHABLE
from swarmd.rawclock import run_on_raw_clock
from tests.daemon_support import run_domain, write_bundle
from tests.test_cmd_reply_lost import COMMAND_ID, PlayedCommander
from tests.test_takeoff_loopback import Swarm

ARGS = {
    "takeoff": ["takeoff", "--alt", "5", "--timeout", "0.5"],
    "land": ["land", "--timeout", "1"],
    "abort": ["abort", "--timeout", "1"],
}


def _run_on_a_stopping_commander(workdir: Path, argv: list[str]) -> int:
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)
    sock = str(workdir / "uav1.sock")

    async def main() -> int:
        commander = swarm.daemon(0)
        await commander.start()
        swarm.daemons.append(commander)
        try:
            app = commander.app
            assert app is not None
            await app.stop()  # Daemon.stop's first step: the control socket still answers
            code: int = await asyncio.to_thread(swarmctl.main, [*argv, "--socket", sock])
            return code
        finally:
            await swarm.stop()

    with capture_logs():  # the daemon's lines, off the stdout swarmctl prints on
        return run_on_raw_clock(main())


@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.parametrize("kind", sorted(ARGS))
def test_a_command_asked_of_a_stopping_daemon_exits_not_reachable_nothing_sent(
    workdir: Path, kind: str, as_json: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    """[fails on main: exit 64, 'swarmctl: the daemon is stopping']"""
    argv = [*ARGS[kind], "--json"] if as_json else ARGS[kind]
    code = _run_on_a_stopping_commander(workdir, argv)
    out, err = capsys.readouterr()
    assert code == EX_UNREACHABLE, err
    assert "stopping" in err and f"the {kind.upper()} command was not sent" in err, err
    if as_json:  # as every other exit 2: nothing on stdout (a script reads the code)
        assert out == ""


def test_the_refusal_carries_its_code_on_the_wire() -> None:
    """The control protocol's error shape: a coded refusal adds ``code``; an uncoded one
    (a bad altitude) stays ``{"ok": false, "error": ...}``. [fails on main: no ``code``]"""

    def stopping(_request: object) -> None:
        raise RequestInvalid("the daemon is stopping", code=STOPPING)

    def bad(_request: object) -> None:
        raise RequestInvalid("bad altitude")

    server = ControlServer("unused.sock", {"takeoff": stopping, "command": bad})
    refused = server.dispatch(b'{"cmd": "takeoff"}')
    assert refused["ok"] is False and refused["code"] == STOPPING
    assert server.dispatch(b'{"cmd": "command"}') == {"ok": False, "error": "bad altitude"}


def test_a_daemon_stopping_while_swarmctl_follows_a_sent_command_says_it_was_sent(
    workdir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Guard: the code says the daemon ran nothing of *this* request. A command already
    sent is out there: exit 1 and where to look, as for any loss while following
    (tests/test_cmd_reply_lost.py), never 2 or "not sent"."""
    sock = workdir / "c.sock"
    daemon = PlayedCommander(sock, "none", "closed", follow_stopping=True)
    try:
        code = swarmctl.main(["land", "--socket", str(sock), "--timeout", "1"])
    finally:
        daemon.close()
    err = capsys.readouterr().err
    assert len(daemon.taken) == 1
    assert code == EX_FAILED, err
    assert f"swarmctl outcomes {COMMAND_ID:#x}" in err and "not sent" not in err, err
