"""Issue 10's attacks on the drone's own ports and the operator's terminal (docs/security.md,
"Attack tests", attacks 6 and 8), each from a host on the swarm's LAN that is not in the
bundle: forged autopilot heartbeats to the PX4 link from the Wi-Fi and from a local user,
and a foreign participant whose name carries terminal escape sequences.

The swarm, the attacker, the three things every test asserts and the rules they share are
``tests/attacker/lab.py``'s. Seen failing against main before the defences (f0f3378) for the
attack's own reason: "armed" from forged heartbeats.
"""

from __future__ import annotations

import json
import time
from typing import Final

import pytest

from swarmd.px4.constants import COMP_ID_AUTOPILOT1
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import Heartbeat as MavHeartbeat
from swarmd.rtps.types import GuidPrefix
from tests.attacker import forge
from tests.attacker.host import drain
from tests.attacker.lab import LEAD, M1, PX4_PORT, Lab
from tests.attacker.swarm import FlashedSwarm, until

pytestmark = [pytest.mark.netns]

TERMINAL_UNSAFE: Final = ("\x1b", "\x07", "\x9b", "\u202e", "\x00", "\r")


# -- 6. the PX4 link from the Wi-Fi side ---------------------------------------------------


def _px4_sockets(sw: FlashedSwarm, i: int) -> list[str]:
    """Local addresses of drone i's UDP sockets on the PX4 port."""
    shown = sw.lan[i].run(["ss", "-Hlun", f"sport = :{PX4_PORT}"]).stdout
    return [line.split()[3] for line in shown.splitlines() if line.strip()]


def test_px4_link_forged_heartbeats_and_interception_refused(lab: Lab) -> None:
    """From the Wi-Fi: forged autopilot heartbeats to the drone's MAVLink port, from a socket
    that would receive whatever the bridge sends back. From the drone itself (any local
    user without the key): the same heartbeats on loopback."""
    sw, atk = lab.swarm, lab.attacker
    sysid = sw.participant(M1).mavlink_sysid
    codec = MavlinkCodec(sysid, COMP_ID_AUTOPILOT1)  # no key: the attacker has none
    armed = MavHeartbeat(
        autopilot=12, vehicle_type=2, base_mode=0x80 | 0x01, custom_mode=0x04030000,
        system_status=4,
    )  # fmt: skip
    # the link listens on loopback only: nothing on the Wi-Fi address can be heard
    assert _px4_sockets(sw, M1) == [f"127.0.0.1:{PX4_PORT}"], _px4_sockets(sw, M1)
    before, vehicle = lab.refusals(), lab.vehicle_commands()
    local = sw.lan[M1].socket()  # a local user on the drone: same namespace, no key
    local.bind(("127.0.0.1", 0))
    sock = atk.listener(14550)
    seen_armed = False
    received: list[bytes] = []
    forged = 0
    try:
        deadline = time.monotonic() + 3.0
        for _ in range(60):  # 20 Hz for at most 3 s
            if time.monotonic() > deadline:
                break
            forged += 1
            frame = codec.encode(armed)
            sock.sendto(frame, (sw.lan[M1].address, PX4_PORT))
            local.sendto(frame, ("127.0.0.1", PX4_PORT))
            received += drain(sock, 0.05)
            px4 = sw.status(M1)["px4"]["readiness"]
            seen_armed = seen_armed or px4.get("reason") == "armed" or px4.get("armed") is True
    finally:
        received += drain(sock, 1.0)
        sock.close()
        local.close()
    assert not seen_armed, "forged heartbeats made the drone report armed"
    assert received == [], f"the drone's MAVLink went to the attacker: {len(received)} datagrams"
    refused = {k: v for k, v in lab.refused_since(before, M1).items() if k.startswith("px4.")}
    assert sum(refused.values()) >= forged, refused  # every local forgery: dropped, counted
    assert lab.vehicle_commands() == vehicle
    lab.assert_commander_commands_all()


# -- 8. escape sequences in names ----------------------------------------------------------

HOSTILE_NAME: Final = "\x1b[2J\x1b[Hswarm OK\x07\x9b31m\u202eevil\x1b]0;owned\x07"


def test_escape_sequences_in_names_are_made_safe(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    prefix = GuidPrefix(bytes.fromhex("0a0b0c0d0e0f101112131415"))
    for _ in range(3):
        atk.multicast(forge.foreign_participant(prefix, HOSTILE_NAME, lab.sn()))
        time.sleep(0.2)

    def listed() -> bool:
        return any(f.get("name") == HOSTILE_NAME for f in sw.status(LEAD)["foreign"])

    until(listed, lambda: sw.status(LEAD)["foreign"], 20)
    as_json = json.loads(sw.swarmctl(LEAD, "status", "--json").stdout)
    assert HOSTILE_NAME in [f["name"] for f in as_json["foreign"]]  # --json: the exact value
    for args in (["status"], ["peers"], ["watch", "--count", "1", "--interval", "0.1"]):
        proc = sw.swarmctl(LEAD, *args)
        assert proc.returncode == 0, proc.stderr
        bad = [c for c in TERMINAL_UNSAFE if c in proc.stdout]
        assert not bad, f"swarmctl {' '.join(args)} printed {bad!r}"
    shown = sw.swarmctl(LEAD, "status").stdout
    assert "\\x1b[2J" in shown or "\\e[2J" in shown, shown  # visible, not executed
    lab.assert_commander_commands_all()
