"""What the operator sees in flight (issue 20): the daemon's ring of peer changes, the peer
table's link quality and last heard, ``swarmctl watch`` printing peers lost and regained,
and the JSON keeping exact (hostile) peer strings while the terminal gets them escaped.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path
from typing import Any

import pytest

from swarmd.cli import status_cmd, swarmctl
from swarmd.cli.status_cmd import new_peer_changes, render_peer_changes, render_status
from swarmd.peerlog import MAX_PEER_CHANGES, PeerChangeKind, PeerHistory
from tests.daemon_support import BundleFiles, run_domain, write_bundle
from tests.test_daemon_loopback import _daemon, _peer, _until

WALL = 1_700_000_000.0  # a fixed wall clock for the renderings


def _history() -> PeerHistory:
    h = PeerHistory()
    h.record(10.0, "uav2", PeerChangeKind.DISCOVERED, reason="multicast", link_quality_permille=810)
    h.record(
        40.0,
        "uav2",
        PeerChangeKind.LOST,
        reason="lease",
        link_quality_permille=420,
        last_heard=34.0,
    )
    h.record(55.5, "uav2", PeerChangeKind.DISCOVERED, reason="directed", link_quality_permille=700)
    h.record(60.0, "uav3", PeerChangeKind.RESTARTED, link_quality_permille=900, last_heard=59.9)
    return h


def test_a_rediscovery_is_a_regain_and_the_ring_says_when_why_and_how_good() -> None:
    st = _history().status(now=61.0)
    assert (st["last_seq"], st["lost"], st["regained"], st["dropped"]) == (4, 1, 1, 0)
    kinds = [(c["peer"], c["change"], c["reason"]) for c in st["changes"]]
    assert kinds == [
        ("uav2", "discovered", "multicast"),
        ("uav2", "lost", "lease"),
        ("uav2", "regained", "directed"),
        ("uav3", "restarted", None),
    ]
    lost = st["changes"][1]
    assert (lost["clock_s"], lost["ago_s"], lost["link_q"], lost["silent_s"]) == (
        40.0,
        21.0,
        0.42,
        6.0,
    )
    assert json.loads(json.dumps(st)) == st  # JSON-ready


def test_the_ring_is_capped_and_counts_what_it_pushed_out() -> None:
    h = PeerHistory()
    for i in range(MAX_PEER_CHANGES + 10):  # a peer flapping at the edge of range
        kind = PeerChangeKind.LOST if i % 2 else PeerChangeKind.DISCOVERED
        h.record(float(i), "uav2", kind)
    st = h.status(now=1000.0)
    assert len(st["changes"]) == MAX_PEER_CHANGES
    assert st["dropped"] == 10
    assert st["changes"][-1]["seq"] == st["last_seq"] == MAX_PEER_CHANGES + 10
    assert st["lost"] == (MAX_PEER_CHANGES + 10) // 2


def test_status_renders_the_peer_table_with_q_and_the_last_changes() -> None:
    status: dict[str, Any] = {
        "node": "uav1",
        "peers": [
            {"name": "uav2", "state": "discovered", "last_heard_s": 0.3, "link_q": 0.7},
            {"name": "uav3", "state": "lost", "last_heard_s": 7.5, "link_q": 0.31},
        ],
        "peer_changes": _history().status(now=61.0),
    }
    lines = render_status(status, wall_now=WALL)
    row = next(ln for ln in lines if ln.strip().startswith("uav3"))
    assert row.split()[:6] == ["uav3", "lost", "7.5", "s", "ago", "0.31"]
    head = lines.index("peer changes: lost 1, regained 1; last 4:")
    changes = lines[head + 1 : head + 5]
    lost_at = time.strftime("%H:%M:%S", time.localtime(WALL - 21.0))
    assert changes[1] == f"  {lost_at}  uav2 LOST (lease)  Q 0.42  last heard 6.0 s before"
    assert changes[2].split()[1:6] == ["uav2", "REGAINED", "(directed)", "Q", "0.70"]


def test_watch_prints_only_new_changes_and_survives_a_daemon_restart() -> None:
    h = _history()
    first, seq = new_peer_changes({"peer_changes": h.status(61.0)}, None, WALL)
    assert (first, seq) == ([], 4)  # the first frame's status lists them already
    h.record(70.0, "uav4", PeerChangeKind.LOST, reason="disposed", link_quality_permille=500)
    fresh, seq = new_peer_changes({"peer_changes": h.status(71.0)}, seq, WALL)
    assert seq == 5 and len(fresh) == 1 and "uav4 LOST (disposed)" in fresh[0]
    again, seq = new_peer_changes({"peer_changes": h.status(72.0)}, seq, WALL)
    assert (again, seq) == ([], 5)
    reborn = PeerHistory()  # the daemon restarted: its numbering starts over
    reborn.record(1.0, "uav2", PeerChangeKind.DISCOVERED)
    lines, seq = new_peer_changes({"peer_changes": reborn.status(2.0)}, seq, WALL)
    assert seq == 1 and len(lines) == 1 and "uav2 DISCOVERED" in lines[0]
    assert new_peer_changes({"node": "old daemon"}, 3, WALL) == ([], 3)


HOSTILE = "uav\x1b[2J9\u202e"


def test_peer_strings_are_escaped_on_the_terminal_and_exact_in_json() -> None:
    h = PeerHistory()
    h.record(1.0, HOSTILE, PeerChangeKind.LOST, reason="lease\x07\x9b31m")
    st: dict[str, Any] = {
        "peers": [{"name": HOSTILE, "state": "lost", "link_q": 0.5}],
        "peer_changes": h.status(2),
    }
    text = "\n".join(render_status(st, wall_now=WALL))
    text += "\n".join(render_peer_changes(st["peer_changes"]["changes"], WALL))
    assert "\x1b" not in text and "\u202e" not in text and "\x07" not in text
    assert "\x9b" not in text
    assert "uav\\x1b[2J9\\u202e LOST (lease\\x07\\x9b31m)" in text
    assert json.loads(json.dumps(st))["peer_changes"]["changes"][0]["peer"] == HOSTILE


def test_watch_on_a_pipe_prints_each_change_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    h = _history()
    frames = [h.status(61.0)]
    h.record(62.0, "uav5", PeerChangeKind.LOST, reason="lease", link_quality_permille=300)
    frames += [h.status(63.0), h.status(64.0)]
    replies = iter({"node": "uav1", "peer_changes": f} for f in frames)

    class Client:
        def __init__(self, _path: str) -> None:
            pass

        def __enter__(self) -> Client:
            return self

        def __exit__(self, *_exc: object) -> None:
            pass

        def request(self, _cmd: str) -> dict[str, Any]:
            return next(replies)

        def close(self) -> None:
            pass

    monkeypatch.setattr(status_cmd, "ControlClient", Client)
    monkeypatch.setattr(time, "sleep", lambda _s: None)
    assert swarmctl.main(["watch", "--count", "3", "--interval", "0", "--socket", "x"]) == 0
    out = capsys.readouterr().out
    news = [ln for ln in out.splitlines() if ln.startswith("peer change: ")]
    assert len(news) == 1 and "uav5 LOST (lease)  Q 0.30" in news[0]


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)


def test_a_daemon_serves_each_peers_quality_and_its_lost_and_regained(
    workdir: Path, files: BundleFiles
) -> None:
    """Two daemons on loopback: uav2 leaves and comes back; uav1's status carries uav2's
    advertised link quality (its static 0.8), its last heard time, and the changes."""

    async def main() -> None:
        a, b = _daemon(workdir, files, "uav1"), _daemon(workdir, files, "uav2")
        await a.start()
        await b.start()
        try:
            await _until(lambda: _peer(a.status(), "uav2")["state"] == "discovered", "uav2")
            peer = _peer(a.status(), "uav2")
            assert peer["link_q"] == 0.8 and peer["times_discovered"] == 1
            assert isinstance(peer["last_heard_s"], float)
            await b.stop("test")
            await _until(lambda: _peer(a.status(), "uav2")["state"] == "lost", "uav2 lost")
            b = _daemon(workdir, files, "uav2")
            await b.start()
            await _until(lambda: _peer(a.status(), "uav2")["state"] == "discovered", "regain")
            st = a.status()
            changes = [(c["peer"], c["change"]) for c in st["peer_changes"]["changes"]]
            assert changes[:3] == [
                ("uav2", "discovered"),
                ("uav2", "lost"),
                ("uav2", "regained"),
            ]
            lost = st["peer_changes"]["changes"][1]
            assert lost["reason"] == "disposed" and lost["link_q"] == 0.8
            assert _peer(st, "uav2")["times_discovered"] == 2
        finally:
            await a.stop("test")
            await b.stop("test")

    asyncio.run(main())
