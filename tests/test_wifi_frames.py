"""bench/wifi/frames.py: classing captured frames as the ns-3 channel does, ACKs included."""

from __future__ import annotations

from bench.wifi import frames
from bench.wifi.frames import Frame

# Captured from real `swarmd run` daemons (python -m bench.wifi.frames --n 10): uav2's
# readiness to uav1's user port 7411, whole; uav2's SPDP to 7400, its first 64 bytes.
READINESS = bytes.fromhex(
    "52545053020353575357a67197de163d000000011505440000001000000001040000010301000000"
    "020000000001000005000000756176320000000002000000000000000d0000007078345f64697361"
    "626c656400000000ffffe8038a831800c182046b010000002e7a294397dc195dcab9da68ebe2b11f"
)
SPDP_HEAD = bytes.fromhex(
    "52545053020353575357a67197de163d0000000109010800c182046b005c072d1505400100001000"
    "000100c7000100c200000000010000000003000015000400"
)


def test_readiness_is_one_user_data_submessage_and_the_authenticator() -> None:
    assert frames.rtps_class(READINESS, 7411) == ("rtps_user", "DATA+0x8A")


def test_spdp_is_discovery_by_its_builtin_writer() -> None:
    cls, ids = frames.rtps_class(SPDP_HEAD, 7400)
    assert cls == "rtps_discovery" and ids.startswith("INFO_TS+DATA")


def test_port_rule_decides_when_no_submessage_names_an_entity() -> None:
    header_only = READINESS[:20]
    assert frames.rtps_class(header_only, 7400)[0] == "rtps_discovery"
    assert frames.rtps_class(header_only, 7411)[0] == "rtps_user"


def test_each_unicast_frame_brings_one_ack_and_group_frames_none() -> None:
    launch = 100.0
    sent = [Frame(launch + 1.5, m, "uav1", True, "rtps_user", "DATA+0x8A") for m in range(1, 10)]
    sent += [
        Frame(launch + 0.2, m, "239.255.0.1", False, "rtps_discovery", "DATA") for m in range(10)
    ]
    text = frames.report(sent, launch, window_s=3, steady_from=1)
    rows = {line.split()[0]: line.split() for line in text.splitlines()[1:4]}
    # columns: rtps_discovery, rtps_user, zenoh, other (each data + ACKs), channel total
    assert rows["0"][1:] == ["10+0", "0+0", "0+0", "0+0", "10"]
    assert rows["1"][1:] == ["0+0", "9+9", "0+0", "0+0", "18"]
    assert "0.50  rtps_user: uav2 -> uav1 DATA+0x8A" in text  # 1 frame over 2 steady seconds
