"""A fixed link quality: the last resort, and the bench/testbed setting."""

from __future__ import annotations

from swarmd.discovery.inputs import LinkSample
from swarmd.link import SourceName
from swarmd.link.quality import clamp01


class StaticSource:
    """Always reports ``q``."""

    name = SourceName.STATIC

    def __init__(self, q: float) -> None:
        if not 0.0 <= q <= 1.0:
            raise ValueError(f"static link quality must be in [0, 1], not {q}")
        self._sample = LinkSample(q=clamp01(q), source=self.name)

    async def read(self) -> LinkSample:
        return self._sample

    def close(self) -> None:
        pass
