"""nl80211 link source: kernel-format messages built and decoded by pyroute2's own marshal."""

from __future__ import annotations

import asyncio
import errno
from collections.abc import AsyncIterator
from typing import Any

import pytest
from pyroute2.netlink.exceptions import NetlinkError
from pyroute2.netlink.nl80211 import NL80211_NAMES, MarshalNl80211, nl80211cmd

from swarmd.link import nl80211 as nl
from swarmd.link.source import LinkUnavailable


def _station(
    mac: str,
    *,
    signal: int | None = None,
    signal_avg: int | None = None,
    inactive_ms: int | None = None,
    bitrate32: int | None = None,
) -> nl80211cmd:
    info: list[list[Any]] = []
    if signal is not None:
        info.append(["NL80211_STA_INFO_SIGNAL", signal])
    if signal_avg is not None:
        info.append(["NL80211_STA_INFO_SIGNAL_AVG", signal_avg])
    if inactive_ms is not None:
        info.append(["NL80211_STA_INFO_INACTIVE_TIME", inactive_ms])
    if bitrate32 is not None:
        info.append(
            ["NL80211_STA_INFO_TX_BITRATE", {"attrs": [["NL80211_RATE_INFO_BITRATE32", bitrate32]]}]
        )
    m = nl80211cmd()
    m["cmd"] = NL80211_NAMES["NL80211_CMD_NEW_STATION"]
    m["version"] = 1
    m["attrs"] = [
        ["NL80211_ATTR_IFINDEX", 3],
        ["NL80211_ATTR_MAC", mac],
        ["NL80211_ATTR_STA_INFO", {"attrs": info}],
    ]
    return m


def _survey(freq: int, *, noise: int | None, in_use: bool) -> nl80211cmd:
    attrs: list[list[Any]] = [["NL80211_SURVEY_INFO_FREQUENCY", freq]]
    if noise is not None:
        attrs.append(["NL80211_SURVEY_INFO_NOISE", noise & 0xFF])  # the kernel's s8 on the wire
    if in_use:
        attrs.append(["NL80211_SURVEY_INFO_IN_USE", True])
    m = nl80211cmd()
    m["cmd"] = NL80211_NAMES["NL80211_CMD_NEW_SURVEY_RESULTS"]
    m["version"] = 1
    m["attrs"] = [["NL80211_ATTR_IFINDEX", 3], ["NL80211_ATTR_SURVEY_INFO", {"attrs": attrs}]]
    return m


def _kernel_roundtrip(*msgs: nl80211cmd) -> list[Any]:
    """Encode to the kernel's byte format, concatenated as in one recv, and decode back."""
    data = b""
    for m in msgs:
        m.encode()
        data += m.data
    return list(MarshalNl80211().parse(data))


def test_station_mode_prefers_signal_average_and_reads_bitrate() -> None:
    msgs = _kernel_roundtrip(
        _station("02:00:00:00:00:01", signal=-58, signal_avg=-61, bitrate32=1300)
    )
    [sta] = nl.parse_stations(msgs)
    assert sta == nl.StationSignal("02:00:00:00:00:01", -61.0, None, 130.0)


def test_station_without_average_uses_last_signal_and_no_signal_is_skipped() -> None:
    msgs = _kernel_roundtrip(
        _station("02:00:00:00:00:01", signal=-70), _station("02:00:00:00:00:02")
    )
    assert [(s.mac, s.signal_dbm) for s in nl.parse_stations(msgs)] == [
        ("02:00:00:00:00:01", -70.0)
    ]


def test_survey_noise_is_the_in_use_channel_and_signed() -> None:
    msgs = _kernel_roundtrip(
        _survey(2412, noise=-80, in_use=False), _survey(2437, noise=-92, in_use=True)
    )
    assert nl.parse_noise(msgs) == -92.0


def test_survey_without_noise_or_in_use_channel_gives_none() -> None:
    assert nl.parse_noise(_kernel_roundtrip(_survey(2437, noise=None, in_use=True))) is None
    assert nl.parse_noise(_kernel_roundtrip(_survey(2437, noise=-92, in_use=False))) is None


def test_snr_from_signal_and_noise_follows_paper_eq2() -> None:
    stations = nl.parse_stations(_kernel_roundtrip(_station("02:00:00:00:00:01", signal_avg=-62)))
    sample = nl.sample_from_nl80211(stations, -92.0)
    assert sample is not None
    assert sample.snr_db == 30.0
    assert sample.q == pytest.approx((30 - 25) / 15)
    assert (sample.signal_dbm, sample.noise_dbm, sample.source) == (-62.0, -92.0, "nl80211")


def test_without_noise_q_is_cfg80211_quality_over_70() -> None:
    stations = [nl.StationSignal("02:00:00:00:00:01", -75.0)]
    sample = nl.sample_from_nl80211(stations, None)
    assert sample is not None
    assert sample.snr_db is None
    assert sample.q == pytest.approx(35 / 70)


def test_mesh_neighbours_median_ignores_stale_neighbours() -> None:
    msgs = _kernel_roundtrip(
        _station("02:00:00:00:00:01", signal_avg=-50, inactive_ms=100),
        _station("02:00:00:00:00:02", signal_avg=-70, inactive_ms=200),
        _station("02:00:00:00:00:03", signal_avg=-60, inactive_ms=300),
        _station("02:00:00:00:00:04", signal_avg=-20, inactive_ms=nl.STALE_STATION_MS + 1),
    )
    stations = nl.parse_stations(msgs)
    assert len(stations) == 4
    assert nl.link_signal(stations) == -60.0


def test_all_stale_still_gives_a_signal_and_none_gives_none() -> None:
    stale = [nl.StationSignal("02:00:00:00:00:01", -66.0, nl.STALE_STATION_MS * 2)]
    assert nl.link_signal(stale) == -66.0
    assert nl.sample_from_nl80211([], -90.0) is None


class _FakeIW:
    """Stands in for pyroute2's AsyncIW; replies with kernel-format decoded messages."""

    stations: list[Any] = []
    surveys: list[Any] = []
    bind_error: BaseException | None = None
    dump_error: BaseException | None = None
    closed = 0

    async def bind(self) -> None:
        if self.bind_error is not None:
            raise self.bind_error

    async def _gen(self, msgs: list[Any]) -> AsyncIterator[Any]:
        if self.dump_error is not None:
            raise self.dump_error
        for m in msgs:
            yield m

    async def get_stations(self, ifindex: int) -> AsyncIterator[Any]:
        return self._gen(self.stations)

    async def survey(self, ifindex: int) -> AsyncIterator[Any]:
        return self._gen(self.surveys)

    def close(self) -> None:
        type(self).closed += 1


@pytest.fixture
def fake_iw(monkeypatch: pytest.MonkeyPatch) -> type[_FakeIW]:
    cls = type("FakeIW", (_FakeIW,), {"stations": [], "surveys": [], "closed": 0})
    monkeypatch.setattr("pyroute2.AsyncIW", cls)
    return cls


def test_source_reads_through_async_iw(fake_iw: type[_FakeIW]) -> None:
    fake_iw.stations = _kernel_roundtrip(_station("02:00:00:00:00:01", signal_avg=-57))
    fake_iw.surveys = _kernel_roundtrip(_survey(5180, noise=-95, in_use=True))
    src = nl.Nl80211Source("lo")
    sample = asyncio.run(src.read())
    assert sample.q == pytest.approx((38 - 25) / 15)
    assert (sample.snr_db, sample.source) == (38.0, "nl80211")
    assert [s.mac for s in src.stations] == ["02:00:00:00:00:01"]
    src.close()
    assert fake_iw.closed == 1


def test_source_no_station_is_transient(fake_iw: type[_FakeIW]) -> None:
    with pytest.raises(LinkUnavailable, match="no station") as info:
        asyncio.run(nl.Nl80211Source("lo").read())
    assert not info.value.permanent


def test_source_missing_family_is_permanent(fake_iw: type[_FakeIW]) -> None:
    fake_iw.bind_error = NetlinkError(errno.ENOENT, "No such file or directory")
    with pytest.raises(LinkUnavailable, match="no nl80211 family") as info:
        asyncio.run(nl.Nl80211Source("lo").read())
    assert info.value.permanent


def test_source_not_wireless_is_permanent(fake_iw: type[_FakeIW]) -> None:
    fake_iw.dump_error = NetlinkError(errno.ENODEV, "No such device")
    with pytest.raises(LinkUnavailable, match="not a wireless") as info:
        asyncio.run(nl.Nl80211Source("lo").read())
    assert info.value.permanent


def test_source_missing_interface_is_transient() -> None:
    with pytest.raises(LinkUnavailable, match="does not exist") as info:
        asyncio.run(nl.Nl80211Source("nosuchif0").read())
    assert not info.value.permanent


def test_real_kernel_on_loopback_retires_the_source() -> None:
    # Here the kernel has no nl80211 family; on a machine with Wi-Fi, lo is not wireless.
    # Either way the real pyroute2 path must end in a permanent, explained LinkUnavailable.
    with pytest.raises(LinkUnavailable) as info:
        asyncio.run(nl.Nl80211Source("lo").read())
    assert info.value.permanent
    assert "nl80211" in info.value.reason
