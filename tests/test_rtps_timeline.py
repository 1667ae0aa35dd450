"""swarmd_lab.rtps_timeline: the SPDP datagrams about one participant at one port, from
tshark's field rows (the capture side is exercised by tests/test_ros2_reboot_netns.py with
SWARMD_ROS2_PCAP set)."""

from __future__ import annotations

from swarmd_lab.rtps_timeline import SpdpArrival, last_life, spdp_arrivals

TALKER = "010f0001000058bdc8ba74b6"
MONITOR_PORT = 9166
EDP = "eProsimaEDPStatic_Writer_ALIVE_ID_8,eProsimaEDPStatic_Reader_ALIVE_ID_9"


def _row(
    at: float,
    src: int,
    sn: str,
    *,
    dst: int = MONITOR_PORT,
    prefix: str = TALKER,
    writer: str = "0x000100c2",
    status: str = "",
    names: str = "",
    icmpv6: str = "",
) -> list[str]:
    return [str(at), "", icmpv6, str(src), str(dst), prefix, writer, sn, status, names]


def test_arrivals_tell_the_relay_from_the_node_and_count_static_endpoints() -> None:
    rows = [
        _row(10.0, 60790, "1"),
        _row(10.001, 60790, "2", names="PARTICIPANT_TYPE," + EDP),
        _row(10.002, 7399, "7712725579497209877"),
        _row(10.5, 7399, "7712725579497209882", status="0x00000003"),
        # not about the talker at the monitor: another port, another participant, SEDP,
        # and the same datagram quoted back in an ICMPv6 error
        _row(10.6, 60790, "3", dst=9164),
        _row(10.6, 54267, "7", prefix="010f0001000158bdc8ba74b6"),
        _row(10.6, 60790, "4", writer="0x000003c2"),
        _row(10.6, 60790, "5", icmpv6="1"),
    ]
    assert spdp_arrivals(rows, MONITOR_PORT, TALKER) == [
        SpdpArrival(10.0, False, 1, False, 0),
        SpdpArrival(10.001, False, 2, False, 2),
        SpdpArrival(10.002, True, 7712725579497209877, False, 0),
        SpdpArrival(10.5, True, 7712725579497209882, True, 0),
    ]


def test_the_last_life_starts_at_the_nodes_last_first_announcement() -> None:
    arrivals = [
        SpdpArrival(0.0, False, 1, False, 0),
        SpdpArrival(5.0, False, 9, False, 6),
        SpdpArrival(29.999, True, 100, False, 0),  # the relay's, just before
        SpdpArrival(30.0, False, 1, False, 0),
        SpdpArrival(30.5, True, 101, True, 0),
    ]
    assert last_life(arrivals) == arrivals[2:]
    assert last_life(arrivals[1:2]) == arrivals[1:2]
