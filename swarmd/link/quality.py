"""From raw radio readings to the paper's normalised link quality Q in [0, 1].

Paper section 4.1: when the driver reports a link quality LQ, ``Q = LQ / LQmax`` (eq. 1);
when it reports only signal and noise, Q comes from the SNR normalised "within the 25-40 dB
range" (eq. 2): ``Q = clamp((SNR - 25) / 15, 0, 1)``, the reading the project's issue fixes.
The plain-text copy of the paper prints eq. 2 garbled as ``clamp(SNR / 40, 0, 1)``; a floor of
0 dB (``link.snr_floor_db: 0``) reproduces that literal form for comparison.
"""

from __future__ import annotations

from typing import Final

from swarmd.discovery.inputs import LinkSample

SNR_CEIL_DB: Final = 40.0  # paper eq. 2: link improvements saturate beyond 40 dB
SNR_FLOOR_DB: Final = 25.0  # paper eq. 2: communication is stable above 25 dB
# cfg80211_wireless_stats (net/wireless/wext-compat.c): qual = clamp(signal, -110, -40) + 110,
# max_qual 70. The same mapping gives nl80211 readings without a noise figure an LQ/LQmax.
CFG80211_SIGNAL_MIN_DBM: Final = -110.0
CFG80211_SIGNAL_MAX_DBM: Final = -40.0
WEXT_MAX_QUALITY: Final = 70.0


def clamp01(value: float) -> float:
    return min(1.0, max(0.0, value))


def q_from_lq(lq: float, lq_max: float) -> float:
    """Paper eq. 1: ``Q = LQ / LQmax`` (clamped, since some drivers overshoot their max)."""
    if lq_max <= 0:
        raise ValueError(f"maximum link quality must be positive, not {lq_max}")
    return clamp01(lq / lq_max)


def q_from_snr(
    snr_db: float, *, floor_db: float = SNR_FLOOR_DB, ceil_db: float = SNR_CEIL_DB
) -> float:
    """Paper eq. 2: SNR normalised between ``floor_db`` (Q = 0) and ``ceil_db`` (Q = 1)."""
    if ceil_db <= floor_db:
        raise ValueError(f"SNR range is empty: floor {floor_db} dB >= ceiling {ceil_db} dB")
    return clamp01((snr_db - floor_db) / (ceil_db - floor_db))


def lq_from_signal(signal_dbm: float) -> float:
    """The quality cfg80211 reports through wireless extensions for ``signal_dbm`` (0..70)."""
    clamped = min(CFG80211_SIGNAL_MAX_DBM, max(CFG80211_SIGNAL_MIN_DBM, signal_dbm))
    return clamped - CFG80211_SIGNAL_MIN_DBM


def sample_from_signal(
    signal_dbm: float,
    noise_dbm: float | None,
    *,
    source: str,
    snr_floor_db: float = SNR_FLOOR_DB,
) -> LinkSample:
    """Q from signal and (when known) noise: eq. 2 on the SNR, else eq. 1 on cfg80211's LQ."""
    if noise_dbm is None:
        q = q_from_lq(lq_from_signal(signal_dbm), WEXT_MAX_QUALITY)
        return LinkSample(q=q, signal_dbm=signal_dbm, source=source)
    snr = signal_dbm - noise_dbm
    return LinkSample(
        q=q_from_snr(snr, floor_db=snr_floor_db),
        snr_db=snr,
        signal_dbm=signal_dbm,
        noise_dbm=noise_dbm,
        source=source,
    )
