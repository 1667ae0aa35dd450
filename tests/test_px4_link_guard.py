"""The PX4 link's defences without sockets: signing, the autopilot pin, the config checks.

Issue 10, attack 6 (docs/px4.md "Trust on the PX4 link", docs/security.md "The PX4 link:
MAVLink and XRCE").
"""

from __future__ import annotations

import hashlib
import stat
import struct
import subprocess
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from swarmd.cli.status_cmd import render_px4_backend
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.config import ConfigError, parse_config
from swarmd.exitcodes import EX_CONFIG
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, COMP_ID_ONBOARD_COMPUTER
from swarmd.px4.linkguard import AutopilotPin
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import Heartbeat, VehicleCommand
from swarmd.px4.provision import SigningKeyError, signing_key_for
from swarmd.px4.signing import (
    NEW_STREAM_WINDOW,
    Verdict,
    Verifier,
    derive_key,
    parse_key_file,
    px4_key_file,
    timestamp_from_unix,
)
from tests.daemon_support import SWARMD, clean_env, loopback_config, run_domain, write_bundle

KEY = derive_key(bytes(range(32)), "alpha", "uav1")
OTHER_KEY = derive_key(bytes(range(32)), "alpha", "uav2")
T0 = timestamp_from_unix(1_800_000_000.0)
ARMED_HB = Heartbeat(
    autopilot=12, vehicle_type=2, base_mode=128 | 1, custom_mode=0, system_status=4
)


def autopilot(key: bytes | None, stamp: int = T0) -> MavlinkCodec:
    codec = MavlinkCodec(1, COMP_ID_AUTOPILOT1, signing_key=key)
    codec.advance_clock(stamp)
    return codec


def companion(key: bytes | None = KEY) -> MavlinkCodec:
    codec = MavlinkCodec(1, COMP_ID_ONBOARD_COMPUTER, signing_key=key)
    codec.advance_clock(T0)
    return codec


# ---- the key ------------------------------------------------------------------------------


def test_key_is_per_swarm_and_per_node_and_deterministic() -> None:
    secret = bytes(range(32))
    assert derive_key(secret, "alpha", "uav1") == KEY and len(KEY) == 32
    assert len({KEY, OTHER_KEY, derive_key(secret, "beta", "uav1")}) == 3
    assert derive_key(bytes(32), "alpha", "uav1") != KEY
    with pytest.raises(ValueError, match="shorter"):
        derive_key(b"short", "alpha", "uav1")


def test_px4_key_file_is_key_then_little_endian_timestamp() -> None:
    data = px4_key_file(KEY, 0x0102030405)
    assert len(data) == 40 and data[:32] == KEY
    assert struct.unpack("<Q", data[32:]) == (0x0102030405,)
    assert parse_key_file(data, "f") == KEY
    assert parse_key_file(KEY, "f") == KEY
    assert parse_key_file(KEY.hex().encode() + b"\n", "f") == KEY
    for bad in (b"", b"nothex", bytes(32)):
        with pytest.raises(ValueError, match="fix:"):
            parse_key_file(bad, "f")


def test_timestamp_is_ten_microseconds_since_2015() -> None:
    assert timestamp_from_unix(1_420_070_400.0) == 0
    assert timestamp_from_unix(1_420_070_401.0) == 100_000
    assert timestamp_from_unix(0.0) == 0


# ---- the verifier -------------------------------------------------------------------------


def test_good_signature_is_the_spec_construction() -> None:
    frame = autopilot(KEY).encode(ARMED_HB)
    assert frame[2] & 0x01  # incompat flag: signed
    assert hashlib.sha256(KEY + frame[:-6]).digest()[:6] == frame[-6:]
    assert int.from_bytes(frame[-12:-6], "little") == T0
    assert Verifier(KEY, T0).check(frame, 1, 1) is Verdict.OK


def test_unsigned_wrong_key_and_replay_are_refused_and_counted() -> None:
    v = Verifier(KEY, T0)
    assert v.check(autopilot(None).encode(ARMED_HB), 1, 1) is Verdict.UNSIGNED
    assert v.check(autopilot(OTHER_KEY).encode(ARMED_HB), 1, 1) is Verdict.BAD_SIGNATURE
    good = autopilot(KEY).encode(ARMED_HB)
    assert v.check(good, 1, 1) is Verdict.OK
    assert v.check(good, 1, 1) is Verdict.REPLAYED  # same timestamp on the same stream
    assert v.counts == {"ok": 1, "unsigned": 1, "bad_signature": 1, "replayed": 1}


def test_a_new_stream_more_than_a_minute_old_is_a_replay() -> None:
    old = autopilot(KEY, T0 - NEW_STREAM_WINDOW - 1).encode(ARMED_HB)
    assert Verifier(KEY, T0).check(old, 1, 1) is Verdict.REPLAYED
    recent = autopilot(KEY, T0 - NEW_STREAM_WINDOW + 1).encode(ARMED_HB)
    assert Verifier(KEY, T0).check(recent, 1, 1) is Verdict.OK


def test_px4s_frame_from_another_link_replayed_late_is_refused() -> None:
    """PX4 signs every link with one key and one clock, each link with its own id. A frame
    recorded on another of its links (the GCS radio, link id 1) and written onto ours 30 s
    later was a new stream within the minute the spec allows, so it reached the state
    stamped fresh (an old AUTO.LAND could confirm a LAND); and a stream started while PX4
    was silent to us went on taking the recording once PX4 spoke again. Now every frame
    must be newer than all its sender signed, on any link. [main: both replays OK]"""
    tick = 100_000  # 1 s in 10 µs units
    v = Verifier(KEY, T0)
    live = autopilot(KEY, T0)
    radio = MavlinkCodec(1, COMP_ID_AUTOPILOT1, signing_key=KEY, link_id=1)

    def heard(codec: MavlinkCodec, stamp: int) -> Verdict:
        codec.advance_clock(stamp)
        return v.check(codec.encode(ARMED_HB), 1, 1)

    assert heard(live, T0) is Verdict.OK
    assert heard(radio, T0 - 30 * tick) is Verdict.REPLAYED  # recorded 30 s before
    # PX4 silent to us (the residual): a frame recorded meanwhile is newer than all we heard
    assert heard(radio, T0 + 5 * tick) is Verdict.OK
    assert heard(live, T0 + 10 * tick) is Verdict.OK  # PX4 speaks again
    assert heard(radio, T0 + 6 * tick) is Verdict.REPLAYED  # the recording goes on: refused
    assert heard(live, T0 + 11 * tick) is Verdict.OK


def test_a_forged_future_timestamp_does_not_lock_out_the_real_stream() -> None:
    # pymavlink's check_signature records the timestamp before comparing the signature;
    # ours must not: a wrong-key frame at 2^48-1 moves nothing
    v = Verifier(KEY, T0)
    forged = autopilot(OTHER_KEY, (1 << 48) - 10).encode(ARMED_HB)
    assert v.check(forged, 1, 1) is Verdict.BAD_SIGNATURE
    assert v.check(autopilot(KEY).encode(ARMED_HB), 1, 1) is Verdict.OK
    assert v.timestamp == T0


def test_codec_with_a_key_delivers_only_signed_frames() -> None:
    rx = companion()
    stream = autopilot(KEY)
    frames = rx.feed(stream.encode(ARMED_HB), datagram=True)
    assert [f.signed for f in frames] == [True]
    assert rx.feed(autopilot(None).encode(ARMED_HB), datagram=True) == []
    assert rx.feed(autopilot(OTHER_KEY).encode(ARMED_HB), datagram=True) == []
    assert rx.signing_counts == {"ok": 1, "unsigned": 1, "bad_signature": 1, "replayed": 0}
    # the autopilot sees our commands signed, and checks them
    cmd = VehicleCommand.make(400, p1=1.0)
    ap = autopilot(KEY)
    got = ap.feed(companion().encode(cmd), datagram=True)
    assert len(got) == 1 and got[0].signed


@given(st.data())
def test_flipping_any_bit_of_a_signed_frame_gets_it_refused(data: st.DataObject) -> None:
    frame = bytearray(autopilot(KEY).encode(ARMED_HB))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    rx = companion()
    assert rx.feed(bytes(frame), datagram=True) == []


def test_pymavlink_parses_our_signed_frames() -> None:
    # an independent reader with the same key accepts what we send (the spec's signature)
    reader = mavlink.MAVLink(None)
    reader.signing.secret_key = KEY
    msgs = reader.parse_buffer(autopilot(KEY).encode(ARMED_HB))
    assert msgs is not None and msgs[0].get_type() == "HEARTBEAT"
    assert reader.signing.goodsig_count == 1


# ---- the pin ------------------------------------------------------------------------------


def test_first_autopilot_heartbeat_pins_and_others_are_dropped() -> None:
    pin = AutopilotPin()
    assert pin.admit_datagram("127.0.0.1:5000", 0.0)
    assert not pin.admit_frame("127.0.0.1:5000", False, 0.0)  # not a heartbeat: not yet
    assert pin.admit_frame("127.0.0.1:5000", True, 0.1)
    assert pin.address == "127.0.0.1:5000"
    assert not pin.admit_datagram("127.0.0.1:6666", 0.2)
    assert pin.admit_datagram("127.0.0.1:5000", 0.3)
    assert pin.counts == {"dropped_address": 1, "dropped_unpinned": 1, "repins": 0}


def test_a_learned_pin_moves_only_after_the_autopilot_went_silent() -> None:
    pin = AutopilotPin(repin_after_s=5.0)
    assert pin.admit_frame("a:1", True, 0.0)
    assert pin.admit_frame("a:1", False, 4.0)
    assert not pin.admit_datagram("b:2", 8.9)  # a heard 4.9 s ago
    assert pin.admit_datagram("b:2", 9.5)
    assert not pin.admit_frame("b:2", False, 9.5)  # only a heartbeat may re-pin
    assert pin.admit_frame("b:2", True, 9.6)
    assert pin.address == "b:2" and pin.counts["repins"] == 1


def test_a_configured_pin_never_moves() -> None:
    pin = AutopilotPin(configured="127.0.0.1:14580")
    assert not pin.admit_datagram("127.0.0.1:9999", 0.0)
    assert not pin.admit_datagram("127.0.0.1:9999", 1e6)
    assert pin.admit_datagram("127.0.0.1:14580", 1e6)
    assert pin.address == "127.0.0.1:14580" and pin.counts["repins"] == 0


# ---- the config ---------------------------------------------------------------------------

BASE = """\
node: uav1
bundle: {path: /b.swb, trusted_key: /k.pub}
network: {interface: wlan0}
px4:
"""


def px4(lines: str) -> str:
    return BASE + "".join(f"  {line}\n" for line in lines.splitlines())


@pytest.mark.parametrize(
    "connection",
    ["udpin:0.0.0.0:14540", "udpin:[::]:14540", "udpin:10.0.0.2:14540", "udpout:px4.local:14580"],
)
def test_a_network_endpoint_is_refused_with_one_line_naming_the_fix(connection: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(px4(f"connection: {connection}"), "/etc/swarmd/swarmd.yaml")
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith("/etc/swarmd/swarmd.yaml:5: field px4.connection:")
    assert "udpin:127.0.0.1:14540" in text and "allow_network" in text
    assert EX_CONFIG == 78


def test_network_endpoint_with_explicit_opt_in_and_pinned_autopilot() -> None:
    config = parse_config(
        px4("connection: udpin:0.0.0.0:14540\nallow_network: true\nautopilot: 10.41.10.2:14580")
    )
    assert config.px4.allow_network and config.px4.autopilot == "10.41.10.2:14580"


def test_defaults_are_loopback_and_signing_fields_parse() -> None:
    config = parse_config(px4("enabled: true"))
    assert config.px4.connection == "udpin:127.0.0.1:14540"
    assert not config.px4.signing and config.px4.autopilot is None
    config = parse_config(px4("signing: true\nsigning_key: keys/uav1.key"), base=None)
    assert config.px4.signing and config.px4.signing_key == "keys/uav1.key"
    config = parse_config(px4("connection: udpin:localhost:14540"))
    assert config.px4.connection == "udpin:localhost:14540"


@pytest.mark.parametrize(
    ("lines", "field"),
    [
        ("connection: serial:/dev/ttyTHS1:921600\nautopilot: 127.0.0.1:14580", "px4.autopilot"),
        ("autopilot: px4:14580", "px4.autopilot"),
        ("signing: maybe", "px4.signing"),
        ("backend: xrce-agent\nautopilot: 127.0.0.1:14580", "px4.autopilot"),
    ],
)
def test_bad_pin_and_signing_fields(lines: str, field: str) -> None:
    with pytest.raises(ConfigError, match=f"field {field}:"):
        parse_config(px4(lines))


def test_autopilot_pin_with_the_default_connection() -> None:
    config = parse_config(px4("autopilot: 127.0.0.1:14580"))
    assert config.px4.autopilot == "127.0.0.1:14580"


# ---- swarmctl px4 key: the ground and the drone derive the same key ------------------------

MISSION = Path(__file__).resolve().parent.parent / "firmware_bundle" / "missions" / "swarm3.yaml"


def test_swarmctl_px4_key_on_the_ground_matches_the_flashed_drone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    keys, bundle, drone = tmp_path / "keys", tmp_path / "b.swb", tmp_path / "drone"
    assert swarmctl(["bundle", "keygen", "--out", str(keys), "--mission", str(MISSION)]) == 0
    sign = str(keys / "swarm-signing.key")
    assert swarmctl(["bundle", "build", str(MISSION), "-o", str(bundle), "--sign-key", sign]) == 0
    flash = ["bundle", "flash", str(bundle), "--node", "drone-1", "--target", str(drone)]
    assert swarmctl([*flash, "--keys", str(keys)]) == 0
    config = tmp_path / "swarmd.yaml"
    config.write_text(
        f"node: drone-1\nbundle: {{path: {drone / 'bundle.swb'}, trusted_key: "
        f"{drone / 'swarm.pub'}}}\nnetwork: {{interface: lo}}\npx4: {{signing: true}}\n"
    )
    capsys.readouterr()
    assert swarmctl(["px4", "key", "--config", str(config)]) == 0
    on_drone = capsys.readouterr().out.strip()
    ground = ["px4", "key", "--keys", str(keys), "--swarm", "field-test-3", "--node", "drone-1"]
    assert swarmctl(ground) == 0
    assert capsys.readouterr().out.strip() == on_drone and len(on_drone) == 64
    out = tmp_path / "mavlink-signing-key.bin"
    assert swarmctl([*ground, "--out", str(out)]) == 0
    data = out.read_bytes()
    assert len(data) == 40 and data[:32].hex() == on_drone
    assert stat.S_IMODE(out.stat().st_mode) == 0o600
    assert swarmctl(["px4", "key", "--keys", str(keys)]) == 65  # no --swarm/--node: one line
    assert "--config FILE" in capsys.readouterr().err


def test_a_key_file_others_can_read_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "uav1.key"
    path.write_bytes(px4_key_file(KEY, T0))
    path.chmod(0o644)
    with pytest.raises(SigningKeyError, match="chmod 600"):
        signing_key_for(swarm="alpha", node="uav1", key_file=str(path), seed=b"")
    path.chmod(0o600)
    assert signing_key_for(swarm="alpha", node="uav1", key_file=str(path), seed=b"") == KEY
    assert signing_key_for(swarm="alpha", node="uav1", key_file=None, seed=bytes(range(32))) == KEY


def test_swarmctl_status_line_shows_the_pin_signing_and_refusals() -> None:
    backend = {
        "backend": "mavlink",
        "connection": "udpin:127.0.0.1:14540",
        "autopilot": {"pinned": "127.0.0.1:14580", "pin": "learned", "dropped_address": 3,
                      "dropped_unpinned": 1, "repins": 0},
        "signing": {"enabled": True, "ok": 50, "dropped_unsigned": 2, "dropped_bad_signature": 1,
                    "dropped_replayed": 0},
    }  # fmt: skip
    assert render_px4_backend(backend) == (
        "px4 link: mavlink udpin:127.0.0.1:14540, autopilot 127.0.0.1:14580 (learned), "
        "signed (ok 50), refused 7"
    )
    serial = {"backend": "mavlink", "connection": "serial:/dev/ttyTHS1:921600",
              "autopilot": None, "signing": {"enabled": False, "ok": 0}}  # fmt: skip
    assert render_px4_backend(serial) == "px4 link: mavlink serial:/dev/ttyTHS1:921600, unsigned"


# ---- the daemon refuses, with one line and exit 78 ----------------------------------------


def _swarmd_run(workdir: Path, px4: str) -> subprocess.CompletedProcess[str]:
    files = write_bundle(workdir, 2, domain_id=run_domain() + 3)
    cfg = loopback_config(workdir, files)
    cfg.write_text(cfg.read_text() + f"px4:\n{px4}")
    return subprocess.run(
        [SWARMD, "run", "--config", str(cfg)],
        capture_output=True, text=True, timeout=30, env=clean_env(), check=False,
    )  # fmt: skip


def test_daemon_refuses_a_wildcard_px4_listener(workdir: Path) -> None:
    proc = _swarmd_run(workdir, "  connection: udpin:0.0.0.0:14540\n")
    assert proc.returncode == EX_CONFIG
    assert proc.stderr.count("\n") == 1
    assert "field px4.connection: udpin:0.0.0.0:14540 reaches beyond loopback" in proc.stderr
    assert "fix: use udpin:127.0.0.1:14540" in proc.stderr


def test_daemon_refuses_a_signing_key_others_can_read(workdir: Path) -> None:
    key = workdir / "px4.key"
    key.write_bytes(px4_key_file(KEY, T0))
    key.chmod(0o644)
    proc = _swarmd_run(workdir, f"  signing: true\n  signing_key: {key}\n")
    assert proc.returncode == EX_CONFIG, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].endswith(f"fix: chmod 600 {key}")


def test_swarmctl_status_line_names_other_local_users_refused_by_the_xrce_agent() -> None:
    """px4.loopback_user: the agent's drops of other users' datagrams reach the operator."""
    agent = {
        "backend": "xrce-agent",
        "connection": "udp:127.0.0.1:888",
        "session": "established",
        "px4_version": "1.16",
        "refused": {},
        "dropped": {"foreign_user": 12},
        "sender_port_shared": 2,
    }
    assert render_px4_backend(agent) == (
        "px4 link: xrce-agent udp:127.0.0.1:888, session established, PX4 1.16, "
        "dropped 12 datagrams of other local users (2 from PX4's port another user holds too)"
    )
    agent["dropped"] = {}
    assert "other local users" not in render_px4_backend(agent)
