"""The discovery engine's inputs besides datagrams: one link-quality reading.

Discovery owns its input types (design.md: dependencies point inward): the link monitor
(``swarmd.link``) produces ``LinkSample`` values and the engine consumes them through
``update_link_quality``; discovery imports nothing of ``swarmd.link``.
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
    source: str = "static"  # the link source that read it (swarmd.link.SourceName)
