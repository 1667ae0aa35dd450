"""With swarmd as PX4's XRCE agent, the vehicle path (swarmd's PX4 stand-in) puts nothing on
the drone's Wi-Fi side; eProsima's MicroXRCEAgent with PX4's default participant
(UXRCE_DDS_PTCFG=0) does (its SPDP/SEDP), which is also the proof that the capture sees such
traffic (that control needs the third-party agent: XRCE_PEERS, tests/xrce_peers.py)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest
from swarmd_lab.netns import Lan, Namespace, unavailable_reason
from swarmd_lab.xrce import ETH_P_ALL, count_udp

from swarmd.xrce.message import CreateClient, Header, WriteData, encode_message
from tests.xrce_peers import peer_binary, peer_env, standin_argv


def _capture_socket(ns: Namespace) -> socket.socket:
    sock = ns.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    sock.bind(("eth0", 0))
    return sock


def test_wifi_side_sees_no_vehicle_path_packets_with_swarmd_as_agent() -> None:
    """swarmd as the agent of the PX4 stand-in: 8 s of PX4's topics, nothing on eth0."""
    if (why := unavailable_reason()) is not None:
        pytest.skip(why)
    with Lan(1) as lan:
        ns = lan[0]
        # swarmd: the agent backend serves the stand-in's topics for 8 s after the first sample
        sock = _capture_socket(ns)
        serve = [
            sys.executable,
            "-m",
            "swarmd_lab.xrce",
            "serve",
            "--port",
            "8888",
            "--seconds",
            "8",
        ]
        swarmd = ns.popen(serve, stdout=subprocess.PIPE)
        ns.popen(standin_argv(8888))
        counts = count_udp(sock, 90, stop=lambda: swarmd.poll() is not None)
        out, _ = swarmd.communicate(timeout=30)
        served = json.loads(out)
        sock.close()
        ns.stop_children()
        # the vehicle path was busy meanwhile: 17 samples/s at the golden session's rates
        assert served["samples"] > 100, served
        assert counts["udp"] == 0, counts


def test_wifi_side_control_micro_xrce_agent_announces() -> None:
    """Control (third-party, XRCE_PEERS): MicroXRCEAgent with PX4's default participant
    (UXRCE_DDS_PTCFG=0) announces on eth0, so the capture does see such traffic."""
    if (why := unavailable_reason()) is not None:
        pytest.skip(why)
    agent_bin = str(peer_binary("MicroXRCEAgent"))
    with Lan(1) as lan:
        ns = lan[0]
        sock = _capture_socket(ns)
        ns.popen([agent_bin, "udp4", "-p", "8889"], env=peer_env())
        ns.popen(standin_argv(8889, "1.16", "-c", "0"))
        control = count_udp(sock, 20, stop=lambda: False)
        sock.close()
        assert control["rtps"] > 0, control


def test_attacker_on_the_wifi_cannot_reach_the_agent() -> None:
    """A host on the drone's Wi-Fi forges CREATE_CLIENT with PX4's key (which would take the
    session over), WRITE_DATA and garbage to the drone's address, port 8888, while sniffing:
    the agent listens on loopback only, so nothing arrives, nothing moves, nothing answers."""
    if (why := unavailable_reason()) is not None:
        pytest.skip(why)
    forged = [
        encode_message(Header(0x80, 0, 0), [CreateClient(b"\x00\x00\x00\x01", 0x81)]),
        encode_message(Header(0x81, 1, 500), [WriteData(1, 0x0FD5, bytes(80))]),
        bytes(range(64)),
    ]
    with Lan(2) as lan:
        drone, attacker = lan[0], lan[1]
        serve = [sys.executable, "-m", "swarmd_lab.xrce", "serve", "--port", "8888"]
        swarmd = drone.popen([*serve, "--seconds", "6"], stdout=subprocess.PIPE)
        drone.popen(standin_argv(8888))
        sniff = _capture_socket(attacker)
        with attacker.socket() as s:
            for _ in range(50):
                for d in forged:
                    s.sendto(d, (drone.address, 8888))
        seen = count_udp(sniff, 90, stop=lambda: swarmd.poll() is not None)
        out, _ = swarmd.communicate(timeout=30)
        served = json.loads(out)
        sniff.close()
        assert served["sessions"] == 1 and served["dropped"] == {}, served
        assert served["samples"] > 20
        # the attacker hears its own 150 datagrams and no reply (ICMP is not UDP)
        assert seen["udp"] == 150, seen


def test_client_mode_keeps_its_participant_on_loopback() -> None:
    """swarmd as a second client of MicroXRCEAgent: its participant is localhost-only, so with
    PX4's own participant localhost-only too (PTCFG=1) the Wi-Fi side stays silent."""
    if (why := unavailable_reason()) is not None:
        pytest.skip(why)
    agent_bin = str(peer_binary("MicroXRCEAgent"))  # third-party: XRCE_PEERS
    with Lan(1) as lan:
        ns = lan[0]
        sock = _capture_socket(ns)
        ns.popen([agent_bin, "udp4", "-p", "8888"], env=peer_env())
        ns.popen(standin_argv(8888, "1.16", "-c", "1"))
        serve = [sys.executable, "-m", "swarmd_lab.xrce", "serve", "--port", "8888", "--client"]
        swarmd = ns.popen([*serve, "--seconds", "6"], stdout=subprocess.PIPE)
        counts = count_udp(sock, 90, stop=lambda: swarmd.poll() is not None)
        out, _ = swarmd.communicate(timeout=30)
        served = json.loads(out)
        sock.close()
        assert served["samples"] > 20, served  # PX4's topics reached swarmd through DDS
        assert counts["udp"] == 0, counts
