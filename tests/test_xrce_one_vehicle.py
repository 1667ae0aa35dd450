"""One agent, one vehicle (issue 17), on virtual time: the agent core with swarmd's own XRCE
client engine as PX4 and as the second client, the translator's system-id check, and the key
kept with the node's secrets. The same scenarios over real loopback sockets, through the XRCE
backend and the daemon, are in ``test_xrce_one_vehicle_loopback.py``."""

from __future__ import annotations

import os
import stat
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

from swarmd.px4.messages import Heartbeat, SysStatus
from swarmd.px4.xrce_key import XrceKeyError, generate_key, load_or_create
from swarmd.px4.xrce_translate import Px4Translator
from swarmd.xrce.agent import SESSION_TIMEOUT_S, VEHICLE_DEAD_AFTER_S, XrceAgent
from swarmd.xrce.client import CONNECT_PERIOD_S, XrceClient
from swarmd.xrce.events import ClientRefused, SampleReceived, SessionCreated, XrceEvent
from swarmd.xrce.message import CreateClient, Header, StatusAgent, decode_message, encode_message
from swarmd.xrce.px4 import dds_topic, encode_fields
from swarmd.xrce.px4_layouts import LAYOUTS

AGENT = ("127.0.0.1", 8888)
PX4 = ("127.0.0.1", 40000)
OTHER = ("127.0.0.1", 40001)
KEY = (0x1234).to_bytes(4, "big")
OTHER_KEY = (2).to_bytes(4, "big")
STATUS = dds_topic("vehicle_status", "out", 1)  # 1.16's vehicle_status_v1
CMD = dds_topic("vehicle_command", "in")
STEP_S = 0.1


def _client(key: bytes) -> XrceClient:
    return XrceClient(key, subscriptions={CMD: "cmd"}, publications={STATUS: "st"})


def _deliver(agent: XrceAgent, clients: Mapping[Any, XrceClient], now: float) -> None:
    """Every queued datagram both ways until quiet; nothing is lost."""
    for _ in range(200):
        moved = False
        for addr, c in clients.items():
            for data, _dest in c.datagrams_to_send():
                moved = True
                agent.receive_datagram(data, addr, now)
        for data, dest in agent.datagrams_to_send():
            moved = True
            if dest in clients:
                clients[dest].receive_datagram(data, AGENT, now)
        if not moved:
            return


def _events(engine: XrceAgent | XrceClient) -> list[XrceEvent]:
    out: list[XrceEvent] = []
    while (e := engine.next_event()) is not None:
        out.append(e)
    return out


def _run(
    agent: XrceAgent, clients: Mapping[Any, XrceClient], start: float, end: float
) -> list[XrceEvent]:
    """Drive every engine's timers from ``start`` to ``end`` in ``STEP_S`` steps; the agent's
    events in order."""
    events: list[XrceEvent] = []
    now = start
    while now < end:
        now = round(now + STEP_S, 6)
        for c in clients.values():
            c.handle_timer(now)
        agent.handle_timer(now)
        _deliver(agent, clients, now)
        events += _events(agent)
    return events


def _commands_to(client: XrceClient) -> list[bytes]:
    return [e.data for e in _events(client) if isinstance(e, SampleReceived)]


def test_two_clients_by_key_only_the_vehicle_is_served() -> None:
    """Issue 17, scenario 1: keys 1 and 2 at one agent. The agent bound to the vehicle's key
    accepts it, refuses the other on every retry, and commands reach the vehicle only."""
    agent = XrceAgent(expected_key=KEY)
    vehicle, other = _client(KEY), _client(OTHER_KEY)
    clients = {PX4: vehicle, OTHER: other}
    other.connect(AGENT, 0.0)  # the other client is first: the order does not matter
    vehicle.connect(AGENT, 0.0)
    events = _run(agent, clients, 0.0, 20.0)
    assert vehicle.state == "established" and other.state == "connecting"
    assert list(agent.sessions) == [PX4]
    refusals = [e for e in events if isinstance(e, ClientRefused)]
    # the other client retries every CONNECT_PERIOD_S; each retry is refused and counted
    assert len(refusals) >= 20 / CONNECT_PERIOD_S - 1
    assert {(e.source, e.client_key, e.reason) for e in refusals} == {
        (OTHER, OTHER_KEY, "wrong_key")
    }
    # counted at the agent, unanswered: the other client hears nothing and keeps retrying
    assert agent.refused["wrong_key"] == len(refusals) and other.refused == 0
    assert sum(isinstance(e, SessionCreated) for e in events) == 1
    _commands_to(vehicle)
    _commands_to(other)
    assert agent.publish(CMD, b"ARM", 20.0) == 1
    _deliver(agent, clients, 20.0)
    assert _commands_to(vehicle) == [b"ARM"] and _commands_to(other) == []


def test_same_key_from_another_process_is_refused_while_the_vehicle_is_alive() -> None:
    """Issue 17, scenario 2: two processes with the vehicle's key. The first keeps the
    session for the whole run (no replacement), the second is refused, the commands go to
    the first only."""
    agent = XrceAgent(expected_key=KEY)
    vehicle, twin = _client(KEY), _client(KEY)
    clients = {PX4: vehicle, OTHER: twin}
    vehicle.connect(AGENT, 0.0)
    _run(agent, clients, 0.0, 1.0)
    session = agent.sessions[PX4]
    twin.connect(AGENT, 1.0)
    events = _run(agent, clients, 1.0, 21.0)
    assert agent.sessions == {PX4: session} and vehicle.state == "established"
    assert not any(isinstance(e, SessionCreated) for e in events)
    assert agent.refused == {"vehicle_alive": agent.refused["vehicle_alive"]}
    assert agent.refused["vehicle_alive"] >= 19 and twin.refused == 0  # never answered
    for t in range(5):
        assert agent.publish(CMD, b"cmd%d" % t, 21.0) == 1
    _deliver(agent, clients, 21.0)
    assert len(_commands_to(vehicle)) == 5 and _commands_to(twin) == []


def test_a_refusal_tells_no_prober_whether_it_guessed_the_key() -> None:
    """A wrong key and the right key while the vehicle is alive get the same answer: none
    (``test_xrce_key_guess.py`` has the budget side). The refusals that do not look at the key
    are still answered."""
    agent = XrceAgent(expected_key=KEY)
    agent.receive_datagram(encode_message(Header(0x80, 0, 0), [CreateClient(KEY, 0x81)]), PX4, 0.0)
    agent.datagrams_to_send()
    for key in (OTHER_KEY, KEY):
        cc = encode_message(Header(0x80, 0, 0), [CreateClient(key, 0x81)])
        agent.receive_datagram(cc, OTHER, 0.5)
        assert agent.datagrams_to_send() == []
    assert agent.refused == {"wrong_key": 1, "vehicle_alive": 1}
    bad_cookie = encode_message(Header(0x80, 0, 0), [CreateClient(OTHER_KEY, 0x81, cookie=b"XRCX")])
    agent.receive_datagram(bad_cookie, OTHER, 0.5)
    ((reply, dest),) = agent.datagrams_to_send()
    sub = decode_message(reply).submessages[0]
    assert dest == OTHER and isinstance(sub, StatusAgent) and sub.status != 0


def test_a_restarted_px4_is_accepted_once_its_old_session_is_dead() -> None:
    """PX4 restarts behind a new port: refused while the old session could be alive, then
    accepted at its first retry after ``VEHICLE_DEAD_AFTER_S`` of silence; behind the same
    port (a UART, or the same socket) it is accepted at once."""
    agent = XrceAgent(expected_key=KEY)
    old = _client(KEY)
    old.connect(AGENT, 0.0)
    _run(agent, {PX4: old}, 0.0, 5.0)
    last_heard = agent.sessions[PX4].last_heard
    restarted = _client(KEY)  # the old process is gone: nothing more from PX4
    restarted.connect(AGENT, 5.0)
    _deliver(agent, {OTHER: restarted}, 5.0)
    assert restarted.state == "connecting" and agent.refused["vehicle_alive"] == 1
    accepted_at = None
    now = 5.0
    while accepted_at is None and now < 12.0:
        events = _run(agent, {OTHER: restarted}, now, now + STEP_S)
        now = round(now + STEP_S, 6)
        if any(isinstance(e, SessionCreated) and e.source == OTHER for e in events):
            accepted_at = now
    assert accepted_at is not None and list(agent.sessions) == [OTHER]
    assert restarted.state == "established"
    # accepted at its first retry once the old session is dead, not a retry period later
    assert last_heard + VEHICLE_DEAD_AFTER_S <= accepted_at
    assert accepted_at <= last_heard + VEHICLE_DEAD_AFTER_S + CONNECT_PERIOD_S + STEP_S
    # the same address: a restart there is the vehicle itself, taken at once
    again = _client(KEY)
    again.connect(AGENT, 12.0)
    _deliver(agent, {OTHER: again}, 12.0)
    assert again.state == "established" and list(agent.sessions) == [OTHER]


def test_a_local_user_recreating_the_session_every_half_second_never_takes_it() -> None:
    """Issue 17, scenario 4: a local process with the configured key opens a fresh socket
    and sends CREATE_CLIENT every 0.5 s for 60 s while PX4 keeps its session."""
    agent = XrceAgent(expected_key=KEY)
    vehicle = _client(KEY)
    vehicle.connect(AGENT, 0.0)
    _run(agent, {PX4: vehicle}, 0.0, 1.0)
    session = agent.sessions[PX4]
    attempts = 0
    now = 1.0
    while now < 61.0:
        attacker = _client(KEY)
        attacker.connect(AGENT, now)
        _deliver(agent, {PX4: vehicle, ("127.0.0.1", 50000 + attempts): attacker}, now)
        assert attacker.state == "connecting"
        attempts += 1
        _run(agent, {PX4: vehicle}, now, now + 0.5)
        now += 0.5
    assert attempts == 120 and agent.refused == {"vehicle_alive": attempts}
    assert agent.sessions == {PX4: session} and vehicle.state == "established"


def test_the_vehicle_session_still_times_out_and_a_new_one_binds() -> None:
    agent = XrceAgent(expected_key=KEY)
    vehicle = _client(KEY)
    vehicle.connect(AGENT, 0.0)
    _deliver(agent, {PX4: vehicle}, 0.0)
    agent.handle_timer(SESSION_TIMEOUT_S)
    assert not agent.sessions and agent.vehicle is None
    assert agent.publish(CMD, b"x", SESSION_TIMEOUT_S) == 0
    newcomer = _client(KEY)
    newcomer.connect(AGENT, SESSION_TIMEOUT_S)
    _deliver(agent, {OTHER: newcomer}, SESSION_TIMEOUT_S)
    assert list(agent.sessions) == [OTHER] and agent.publish(CMD, b"x", SESSION_TIMEOUT_S) == 1


# ---- the translator: samples of another vehicle ---------------------------------------------


def _status(system_id: int, **values: float | int | bool) -> tuple[str, bytes]:
    layout = LAYOUTS["1.16"]["VehicleStatus"]
    return STATUS, encode_fields(layout, {"system_id": system_id, **values})


def _battery() -> tuple[str, bytes]:
    layout = LAYOUTS["1.16"]["BatteryStatus"]
    return dds_topic("battery_status", "out", layout[1]), encode_fields(
        layout, {"remaining": 0.9, "voltage_v": 16.0}
    )


def test_samples_of_another_vehicle_are_dropped_and_counted() -> None:
    """Issue 17, scenario 3: a client claiming another system id, or spoofing ours between
    the vehicle's own samples: only vehicle_status with our system id moves anything."""
    t = Px4Translator(sysid=1)
    assert t.sample(*_battery()) == []  # whose? no vehicle_status yet
    assert t.unidentified_samples == 1
    assert t.sample(*_status(2, arming_state=2)) == []
    assert (t.foreign_samples, t.foreign_system_id) == (1, 2)
    assert t.sample(*_battery()) == []  # still the other vehicle's session
    hb, sys_status = t.sample(*_status(1, pre_flight_checks_pass=True))
    assert isinstance(hb, Heartbeat) and not hb.armed and isinstance(sys_status, SysStatus)
    assert len(t.sample(*_battery())) == 1
    # interleaved: the other vehicle's "armed" status never reaches readiness
    for _ in range(10):
        assert t.sample(*_status(2, arming_state=2)) == []
        (hb, _sys) = t.sample(*_status(1))
        assert isinstance(hb, Heartbeat) and not hb.armed
    assert t.foreign_samples == 11
    # a new session is nobody's until its vehicle_status says whose
    t.new_session()
    unidentified = t.unidentified_samples
    assert t.sample(*_battery()) == []
    assert t.unidentified_samples == unidentified + 1


# ---- the key, kept with the node's secrets -------------------------------------------------


def test_key_generated_once_kept_across_restarts_mode_0600(tmp_path: Path) -> None:
    first = load_or_create(tmp_path)
    assert first.created and first.path == tmp_path / "px4-xrce-key"
    assert stat.S_IMODE(first.path.stat().st_mode) == 0o600
    assert 1 <= first.value <= 0x7FFF_FFFF  # PX4's UXRCE_DDS_KEY is an INT32
    assert first.path.read_text() == f"{first.value}\n"  # as `param set UXRCE_DDS_KEY` takes it
    again = load_or_create(tmp_path)
    assert (again.value, again.created, again.mode_fixed) == (first.value, False, False)
    assert generate_key(0x5357_4D44) != 0x5357_4D44  # never swarmd's own client key


def test_a_key_file_readable_by_others_is_made_private(tmp_path: Path) -> None:
    path = tmp_path / "px4-xrce-key"
    path.write_text("77\n")
    path.chmod(0o644)
    key = load_or_create(tmp_path)
    assert (key.value, key.mode_fixed, key.created) == (77, True, False)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600


@pytest.mark.parametrize("content", [b"", b"0\n", b"-5\n", b"4294967296\n", b"x" * 100, b"\xff"])
def test_a_bad_key_file_stops_with_one_line_naming_it(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "px4-xrce-key"
    path.write_bytes(content)
    os.chmod(path, 0o600)
    with pytest.raises(XrceKeyError) as info:
        load_or_create(tmp_path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text and "fix:" in text
    assert path.read_bytes() == content  # not replaced: PX4 may hold the old key


def test_a_symlinked_key_file_is_refused(tmp_path: Path) -> None:
    target = tmp_path / "elsewhere"
    target.write_text("5\n")
    (tmp_path / "px4-xrce-key").symlink_to(target)
    with pytest.raises(XrceKeyError, match="px4-xrce-key"):
        load_or_create(tmp_path)


def test_a_fifo_in_place_of_the_key_file_stops_start_up_at_once(tmp_path: Path) -> None:
    """A FIFO planted at the key's path must not hang start-up with no line saying why
    (the floor's reader's rule, ``swarmd/bundle/floor.py``): opened non-blocking, refused
    as not a regular file. Run in a thread so that a hang fails the test instead of the
    suite: then a writer is opened to release the blocked open."""
    path = tmp_path / "px4-xrce-key"
    os.mkfifo(path, 0o600)
    outcome: list[BaseException | None] = []

    def load() -> None:
        try:
            load_or_create(tmp_path)
            outcome.append(None)
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            outcome.append(exc)

    worker = threading.Thread(target=load, daemon=True)
    worker.start()
    worker.join(5.0)
    hung = worker.is_alive()
    if hung:  # release the open that blocks on a FIFO without a writer
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        worker.join(5.0)
    assert not hung, "load_or_create blocked on a FIFO"
    assert len(outcome) == 1 and isinstance(outcome[0], XrceKeyError), outcome
    text = str(outcome[0])
    assert "\n" not in text and str(path) in text and "fix:" in text
