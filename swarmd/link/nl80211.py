"""Link quality from nl80211 (pyroute2 ``AsyncIW``): station signal and survey noise.

In station mode ``GET_STATION`` returns one entry, the access point; on an ad hoc (IBSS)
or 802.11s mesh interface one entry per neighbour, keyed by its MAC. The neighbours' median
average signal stands for the node's link: one weak neighbour does not make the whole link
bad, and one strong one does not hide a bad channel. ``GET_SURVEY`` gives the noise floor of
the channel in use when the driver measures it (many do not), and with it the SNR for paper
eq. 2; without noise, cfg80211's own signal-to-quality mapping gives eq. 1.

Parsing lives in pure functions over decoded messages so tests feed them kernel-format
messages built and decoded by pyroute2's own marshal. Reads need no capability:
GET_STATION and GET_SURVEY carry no admin flag in net/wireless/nl80211.c.
"""

from __future__ import annotations

import errno
import socket
import statistics
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Final

from swarmd.discovery.inputs import LinkSample
from swarmd.link import SourceName
from swarmd.link.quality import SNR_FLOOR_DB, sample_from_signal
from swarmd.link.source import LinkUnavailable

# A neighbour silent this long (NL80211_STA_INFO_INACTIVE_TIME) has left; its stale signal
# would otherwise keep the median up while the drone flies away from it.
STALE_STATION_MS: Final = 10_000
_S8_WRAP: Final = 256
_S8_MAX: Final = 127


@dataclass(frozen=True, slots=True)
class StationSignal:
    """One station (the AP, or an ad hoc/mesh neighbour) as the driver sees it."""

    mac: str
    signal_dbm: float
    inactive_ms: int | None = None
    tx_mbps: float | None = None


def parse_stations(messages: Iterable[Any]) -> list[StationSignal]:
    """``NL80211_CMD_NEW_STATION`` replies to stations with a signal (average preferred)."""
    out: list[StationSignal] = []
    for msg in messages:
        info = msg.get_attr("NL80211_ATTR_STA_INFO")
        if info is None:
            continue
        signal = info.get_attr("NL80211_STA_INFO_SIGNAL_AVG")
        if signal is None:
            signal = info.get_attr("NL80211_STA_INFO_SIGNAL")
        if signal is None:
            continue
        tx = info.get_attr("NL80211_STA_INFO_TX_BITRATE")
        mbps = None
        if tx is not None:
            rate = tx.get_attr("NL80211_RATE_INFO_BITRATE32") or tx.get_attr(
                "NL80211_RATE_INFO_BITRATE"
            )
            mbps = rate / 10 if rate else None  # the kernel counts in 100 kbit/s
        out.append(
            StationSignal(
                mac=str(msg.get_attr("NL80211_ATTR_MAC")),
                signal_dbm=float(signal),
                inactive_ms=info.get_attr("NL80211_STA_INFO_INACTIVE_TIME"),
                tx_mbps=mbps,
            )
        )
    return out


def parse_noise(messages: Iterable[Any]) -> float | None:
    """Noise floor (dBm) of the channel in use from ``NEW_SURVEY_RESULTS``, if measured."""
    for msg in messages:
        survey = msg.get_attr("NL80211_ATTR_SURVEY_INFO")
        if survey is None or not survey.get_attr("NL80211_SURVEY_INFO_IN_USE"):
            continue
        noise = survey.get_attr("NL80211_SURVEY_INFO_NOISE")
        if noise is None:
            return None
        # pyroute2 maps NOISE as u8 while the kernel puts an s8 dBm value there
        return float(noise - _S8_WRAP if noise > _S8_MAX else noise)
    return None


def link_signal(stations: list[StationSignal]) -> float | None:
    """The signal that stands for the link: the median over fresh stations."""
    fresh = [s for s in stations if s.inactive_ms is None or s.inactive_ms <= STALE_STATION_MS]
    chosen = fresh or stations
    if not chosen:
        return None
    return float(statistics.median(s.signal_dbm for s in chosen))


def sample_from_nl80211(
    stations: list[StationSignal], noise_dbm: float | None, *, snr_floor_db: float = SNR_FLOOR_DB
) -> LinkSample | None:
    """The link sample for decoded station and survey replies; None without any station."""
    signal = link_signal(stations)
    if signal is None:
        return None
    return sample_from_signal(
        signal, noise_dbm, source=SourceName.NL80211, snr_floor_db=snr_floor_db
    )


def _netlink_code(exc: BaseException) -> int | None:
    code = getattr(exc, "code", None)
    return code if isinstance(code, int) else None


class Nl80211Source:
    """Asks the kernel over generic netlink (``AsyncIW``) each poll; keeps one socket open."""

    name = SourceName.NL80211

    def __init__(self, interface: str, *, snr_floor_db: float = SNR_FLOOR_DB) -> None:
        self.interface = interface
        self.snr_floor_db = snr_floor_db
        self.stations: list[StationSignal] = []  # last reading's per-neighbour table
        self._iw: Any = None

    async def _bind(self) -> Any:
        from pyroute2 import AsyncIW  # imported late: the daemon can run without it

        iw = AsyncIW()
        try:
            await iw.bind()
        except Exception as exc:
            iw.close()
            if _netlink_code(exc) == errno.ENOENT:
                raise LinkUnavailable(
                    "kernel has no nl80211 family (no Wi-Fi driver loaded)", permanent=True
                ) from None
            raise LinkUnavailable(f"cannot open nl80211: {exc}") from None
        return iw

    async def read(self) -> LinkSample:
        try:
            ifindex = socket.if_nametoindex(self.interface)
        except OSError:
            raise LinkUnavailable(f"interface {self.interface} does not exist") from None
        if self._iw is None:
            self._iw = await self._bind()
        try:
            stations = parse_stations([m async for m in await self._iw.get_stations(ifindex)])
            try:
                noise = parse_noise([m async for m in await self._iw.survey(ifindex)])
            except Exception:  # survey is optional: many drivers have no survey op at all
                noise = None
        except LinkUnavailable:
            raise
        except Exception as exc:
            self.close()
            code = _netlink_code(exc)
            if code in (errno.ENODEV, errno.EOPNOTSUPP):
                raise LinkUnavailable(
                    f"{self.interface} is not a wireless (nl80211) interface", permanent=True
                ) from None
            raise LinkUnavailable(f"nl80211 station dump on {self.interface}: {exc}") from None
        self.stations = stations
        sample = sample_from_nl80211(stations, noise, snr_floor_db=self.snr_floor_db)
        if sample is None:
            raise LinkUnavailable(f"no station on {self.interface} (not associated, no neighbour)")
        return sample

    def close(self) -> None:
        if self._iw is not None:
            iw, self._iw = self._iw, None
            iw.close()
