"""Link quality from wireless extensions: ``/proc/net/wireless``.

Two header lines, then one line per associated interface::

     wlan0: 0000   49.  -61.  -256        0      0      0     12      0        0

status, link quality, level (dBm), noise, then discard and missed-beacon counters; a
trailing ``.`` flags an updated value. cfg80211 drivers report quality 0..70 and always an
invalid noise (-256), see ``cfg80211_wireless_stats`` in net/wireless/wext-compat.c; some
legacy drivers print the level as an unsigned byte. The file only lists an interface while
it is associated, so a missing line is transient.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.discovery.inputs import LinkSample
from swarmd.link import SourceName
from swarmd.link.quality import WEXT_MAX_QUALITY, q_from_lq, q_from_snr
from swarmd.link.source import LinkUnavailable

PROC_NET_WIRELESS: Final = "/proc/net/wireless"
WEXT_INVALID_NOISE_DBM: Final = -256.0  # what cfg80211 prints when the noise is unknown
_UNSIGNED_LEVEL_THRESHOLD: Final = 63.0  # above this a "dBm" level is an unsigned byte


@dataclass(frozen=True, slots=True)
class WextEntry:
    interface: str
    quality: float
    level_dbm: float
    noise_dbm: float | None


def _number(token: str) -> float:
    return float(token.rstrip("."))


def _dbm(value: float) -> float:
    return value - 256.0 if value > _UNSIGNED_LEVEL_THRESHOLD else value


def parse_proc_net_wireless(text: str) -> dict[str, WextEntry]:
    """Every well-formed interface line of ``/proc/net/wireless``; malformed lines are skipped."""
    entries: dict[str, WextEntry] = {}
    for line in text.splitlines()[2:]:
        name, sep, rest = line.partition(":")
        fields = rest.split()
        if not sep or len(fields) < 4:
            continue
        try:
            quality, level, noise = (_number(t) for t in fields[1:4])
        except ValueError:
            continue
        noise_dbm = None if noise <= WEXT_INVALID_NOISE_DBM or noise == 0 else _dbm(noise)
        entries[name.strip()] = WextEntry(name.strip(), quality, _dbm(level), noise_dbm)
    return entries


def sample_from_entry(
    entry: WextEntry, *, max_quality: float = WEXT_MAX_QUALITY, snr_floor_db: float = 0.0
) -> LinkSample:
    """Paper eq. 1 on the driver's LQ; the SNR is reported too when the noise is valid."""
    snr = entry.level_dbm - entry.noise_dbm if entry.noise_dbm is not None else None
    q = q_from_lq(entry.quality, max_quality)
    if q == 0.0 and snr is not None:
        # drivers that fill level/noise but leave quality at 0 (seen on some legacy ones)
        q = q_from_snr(snr, floor_db=snr_floor_db)
    return LinkSample(
        q=q,
        snr_db=snr,
        signal_dbm=entry.level_dbm,
        noise_dbm=entry.noise_dbm,
        source=SourceName.WEXT,
    )


class WextSource:
    """Reads ``/proc/net/wireless`` for one interface."""

    name = SourceName.WEXT

    def __init__(
        self,
        interface: str,
        *,
        path: str = PROC_NET_WIRELESS,
        max_quality: float = WEXT_MAX_QUALITY,
        snr_floor_db: float = 0.0,
    ) -> None:
        self.interface = interface
        self.path = Path(path)
        self.max_quality = max_quality
        self.snr_floor_db = snr_floor_db

    async def read(self) -> LinkSample:
        # A procfs read never blocks on I/O, so it runs on the loop (no executor thread).
        try:
            text = self.path.read_text(encoding="ascii", errors="replace")
        except FileNotFoundError:
            raise LinkUnavailable(
                f"{self.path} does not exist (kernel without wireless extensions)",
                permanent=True,
            ) from None
        except OSError as exc:
            raise LinkUnavailable(f"cannot read {self.path}: {exc.strerror}") from None
        entry = parse_proc_net_wireless(text).get(self.interface)
        if entry is None:
            raise LinkUnavailable(f"{self.interface} not listed in {self.path} (not associated?)")
        return sample_from_entry(
            entry, max_quality=self.max_quality, snr_floor_db=self.snr_floor_db
        )

    def close(self) -> None:
        pass
