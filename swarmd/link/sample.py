"""One link-quality reading, the value the discovery engine turns into a passive timer.

Shared between the link monitor (which produces it) and the discovery engine (which consumes
it through ``update_link_quality``). Kept free of I/O so the sans-IO engine may import it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class LinkSample:
    """A normalised link-quality reading.

    ``q`` is in [0, 1] (the paper's Q = LQ / LQmax, section 3.2); the dBm fields are what the
    source measured, ``None`` when it cannot tell.
    """

    q: float
    snr_db: float | None = None
    signal_dbm: float | None = None
    noise_dbm: float | None = None
    source: str = "static"  # nl80211 | wext | file | static
