"""Link quality from a JSON file that a testbed or an operator writes.

Accepted shapes (one object; the first matching key set wins)::

    {"q": 0.8}                                  Q directly
    {"lq": 49, "lq_max": 70}                    paper eq. 1
    {"snr_db": 32.0}                            paper eq. 2
    {"signal_dbm": -61, "noise_dbm": -95}       paper eq. 2 on signal - noise
    {"signal_dbm": -61}                         cfg80211's LQ mapping

Writers should replace the file atomically (write a temp file, then rename); a torn read
is reported as transient and retried at the next poll.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

from swarmd.discovery.inputs import LinkSample
from swarmd.link import SourceName
from swarmd.link.quality import q_from_lq, q_from_snr, sample_from_signal
from swarmd.link.source import LinkUnavailable


def _num(obj: dict[str, Any], key: str) -> float | None:
    value = obj.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f'"{key}" must be a finite number, not {value!r}')
    return float(value)


def sample_from_json(obj: object, *, snr_floor_db: float = 0.0) -> LinkSample:
    """The sample a decoded link file describes; ``ValueError`` names the bad key."""
    if not isinstance(obj, dict):
        raise ValueError('top level must be a JSON object like {"q": 0.8}')
    q, lq, lq_max = _num(obj, "q"), _num(obj, "lq"), _num(obj, "lq_max")
    snr, signal, noise = _num(obj, "snr_db"), _num(obj, "signal_dbm"), _num(obj, "noise_dbm")
    if q is not None:
        if not 0.0 <= q <= 1.0:
            raise ValueError(f'"q" must be in [0, 1], not {q}')
        return LinkSample(
            q=q, snr_db=snr, signal_dbm=signal, noise_dbm=noise, source=SourceName.FILE
        )
    if lq is not None:
        if lq_max is None or lq_max <= 0:
            raise ValueError('"lq" needs a positive "lq_max"')
        return LinkSample(
            q=q_from_lq(lq, lq_max),
            snr_db=snr,
            signal_dbm=signal,
            noise_dbm=noise,
            source=SourceName.FILE,
        )
    if snr is not None:
        q_snr = q_from_snr(snr, floor_db=snr_floor_db)
        return LinkSample(
            q=q_snr, snr_db=snr, signal_dbm=signal, noise_dbm=noise, source=SourceName.FILE
        )
    if signal is not None:
        return sample_from_signal(signal, noise, source=SourceName.FILE, snr_floor_db=snr_floor_db)
    raise ValueError('no reading: give one of "q", "lq"+"lq_max", "snr_db" or "signal_dbm"')


class FileSource:
    """Reads a small JSON link file each poll; optionally rejects a stale one."""

    name = SourceName.FILE

    def __init__(
        self, path: str, *, max_age_s: float | None = None, snr_floor_db: float = 0.0
    ) -> None:
        self.path = Path(path)
        self.max_age_s = max_age_s
        self.snr_floor_db = snr_floor_db

    async def read(self) -> LinkSample:
        # A few hundred bytes from a local file: reading it on the loop costs less than a
        # thread hop, and a hung NFS mount is not a place this file belongs.
        try:
            st = os.stat(self.path)
            raw = self.path.read_bytes()
        except FileNotFoundError:
            raise LinkUnavailable(f"link file {self.path} does not exist") from None
        except OSError as exc:
            raise LinkUnavailable(f"cannot read link file {self.path}: {exc.strerror}") from None
        if self.max_age_s is not None:
            age = time.time() - st.st_mtime  # wall clock: mtime is wall-clock time
            if age > self.max_age_s:
                raise LinkUnavailable(
                    f"link file {self.path} is stale ({age:.0f} s old > {self.max_age_s:g} s)"
                )
        try:
            return sample_from_json(json.loads(raw), snr_floor_db=self.snr_floor_db)
        except (ValueError, UnicodeDecodeError) as exc:
            raise LinkUnavailable(f"link file {self.path}: {exc}") from None

    def close(self) -> None:
        pass
