"""``px4.backend`` for uXRCE-DDS: config checks in one line, the bridge picks the backend,
``swarmctl status`` names backend, session and PX4 version."""

from __future__ import annotations

import pytest
from swarmd_lab.configs import MINIMAL_CONFIG

from swarmd.cli.status_cmd import render_px4_backend
from swarmd.config import ConfigError, parse_config
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.xrce_backend import DEFAULT_XRCE_CONNECTION, XrceBackend
from swarmd.xrce.client import XrceClient
from swarmd.xrce.message import (
    Create,
    Header,
    ObjectKind,
    StatusAgent,
    decode_message,
    encode_message,
)

MINIMAL = MINIMAL_CONFIG


def test_xrce_backend_defaults_to_a_privileged_loopback_port() -> None:
    """PX4 SITL's 8888 moved below 1024 (issue 18: no local user can take the agent's port),
    the port systemd/swarmd-xrce.socket holds (tests/test_systemd_unit.py checks the unit)."""
    cfg = parse_config(MINIMAL + "px4:\n  backend: xrce-agent\n  xrce_key: 1\n", "s.yaml")
    assert (cfg.px4.backend, cfg.px4.connection, cfg.px4.xrce_key) == (
        "xrce-agent", "udp:127.0.0.1:888", 1,
    )  # fmt: skip
    assert cfg.px4.connection == DEFAULT_XRCE_CONNECTION  # the backend's own default agrees
    cfg = parse_config(MINIMAL + "px4:\n  backend: xrce-client\n  namespace: uav1\n", "s.yaml")
    assert cfg.px4.backend == "xrce-client" and cfg.px4.namespace == "uav1"
    assert cfg.px4.connection == "udp:127.0.0.1:888"  # where its MicroXRCEAgent listens


@pytest.mark.parametrize(
    ("extra", "field", "problem"),
    [
        ("px4:\n  backend: dds\n", "px4.backend", "'dds' is not a backend"),
        ("px4:\n  backend: xrce-agent\n  connection: udpin:127.0.0.1:1\n", "px4.connection",
         "is not an XRCE connection"),
        ("px4:\n  backend: xrce-agent\n  connection: udp:0.0.0.0:8888\n", "px4.connection",
         "reaches beyond loopback"),
        ("px4:\n  backend: xrce-agent\n  xrce_key: 0\n", "px4.xrce_key", "outside"),
        ("px4:\n  backend: xrce-client\n  xrce_domain_id: 233\n", "px4.xrce_domain_id",
         "outside 0..232"),
        ("px4:\n  backend: xrce-client\n  xrce_domain_id: 1.5\n", "px4.xrce_domain_id",
         "not a whole number"),
        ("px4:\n  backend: xrce-client\n  xrce_domain_id: one\n", "px4.xrce_domain_id",
         "expected a number"),
        ("px4:\n  backend: xrce-agent\n  xrce_domain_id: 3\n", "px4.xrce_domain_id",
         "only xrce-client"),
        ("px4:\n  xrce_domain_id: 3\n", "px4.xrce_domain_id", "only xrce-client"),
    ],
)  # fmt: skip
def test_bad_xrce_fields_are_one_line(extra: str, field: str, problem: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(MINIMAL + extra, "s.yaml")
    text = str(info.value)
    assert "\n" not in text and f"field {field}: " in text and problem in text


def test_xrce_client_joins_the_configured_dds_domain() -> None:
    """xrce-client creates its participant in ``px4.xrce_domain_id`` (PX4's and the agent's
    UXRCE_DDS_DOM_ID), default 0 as before; it used to be 0 whatever the config said, so
    with PX4 on another domain swarmd never matched its topics."""
    cfg = parse_config(MINIMAL + "px4:\n  backend: xrce-client\n", "s.yaml")
    assert cfg.px4.xrce_domain_id == 0
    cfg = parse_config(MINIMAL + "px4:\n  backend: xrce-client\n  xrce_domain_id: 7\n", "s.yaml")
    assert cfg.px4.xrce_domain_id == 7
    bridge = Px4Bridge.from_config(
        Px4Config(connection="udp:127.0.0.1:8888", backend="xrce-client", xrce_domain_id=7)
    )
    assert isinstance(bridge.backend, XrceBackend)
    engine = bridge.backend.engine
    assert isinstance(engine, XrceClient)
    engine.connect(("127.0.0.1", 8888), 0.0)
    engine.datagrams_to_send()  # CREATE_CLIENT
    accepted = encode_message(Header(0x81, 0, 0), [StatusAgent(0, 0)])
    engine.receive_datagram(accepted, ("127.0.0.1", 8888), 0.0)
    participants = [
        sub
        for data, _ in engine.datagrams_to_send()
        for sub in decode_message(data).submessages
        if isinstance(sub, Create) and sub.kind == ObjectKind.PARTICIPANT
    ]
    assert [p.domain_id for p in participants] == [7]


def test_bridge_builds_the_configured_backend() -> None:
    bridge = Px4Bridge.from_config(Px4Config(connection="udp:127.0.0.1:8888", backend="xrce-agent"))
    assert isinstance(bridge.backend, XrceBackend) and bridge.backend.mode == "xrce-agent"
    with pytest.raises(ValueError, match="xrce-client reaches its agent over udp"):
        XrceBackend("xrce-client", "serial:/dev/ttyTHS1:921600")


def test_status_line_names_backend_session_and_version() -> None:
    b = XrceBackend("xrce-agent", "udp:127.0.0.1:8888").stats()
    assert render_px4_backend(b) == (
        "px4 link: xrce-agent udp:127.0.0.1:8888, session none, PX4 version not seen yet"
    )
    b.update(session="established", client="127.0.0.1:4000 key 00000001", px4_version="1.16")
    assert render_px4_backend(b).endswith(
        "session established (127.0.0.1:4000 key 00000001), PX4 1.16"
    )
