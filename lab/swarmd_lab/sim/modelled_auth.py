"""The SPDP authenticator as the simulator models it: real bytes and freshness, no Ed25519.

A 1000-drone run delivers ~10^6 SPDP datagrams per engine-minute; verifying each with
Ed25519 would cost ~80 us and turn a 90-second run into hours, while the channel only sees
bytes. So the simulator's ``swarmd-auth`` protocol gives every engine this stand-in:

- ``seal`` writes the real authenticator (PID 0x8A04: receiver tags, tag window, epoch,
  seq, 64 octets) with zero tags and a zero signature, so every datagram has the size, and
  the airtime, of a signed one (the tag window rotates as the daemon's does:
  ``swarmd.auth.tags.ZeroTags``);
- ``check`` runs the real cheap checks (authenticator present, freshness against a
  ``ReplayWindow`` per sender) and skips the signature.

Lab only: it authenticates nothing. The daemon always uses ``swarmd.auth.spdp.SpdpAuth``
with the node's keys; the CPU cost of verifying is measured by ``bench/auth.py``.
"""

from __future__ import annotations

from swarmd.auth.freshness import Freshness, ReplayWindow, SendCounter
from swarmd.auth.keys import SIGNATURE_BYTES
from swarmd.auth.spdp import Refusal, SpdpAuth, open_tail, seal
from swarmd.auth.tags import ZeroTags
from swarmd.rtps.types import GuidPrefix

_ZERO_SIGNATURE = bytes(SIGNATURE_BYTES)


class _ZeroSigner:
    def sign(self, data: bytes) -> bytes:
        return _ZERO_SIGNATURE


_SIGNER = _ZeroSigner()


class ModelledSpdpAuth(SpdpAuth):
    """Bytes and freshness of ``SpdpAuth`` without keys (see the module docstring)."""

    def __init__(self, own_prefix: GuidPrefix, epoch: int, swarm_size: int = 1) -> None:
        # no super(): no keys. ``swarm_size``: the bundle's participants (tags per datagram)
        self._own_prefix = own_prefix
        self._zero_tags = ZeroTags(swarm_size)
        self.counter = SendCounter(epoch)
        self._windows: dict[bytes, ReplayWindow] = {}

    @property
    def own_prefix(self) -> GuidPrefix:
        return self._own_prefix

    def seal(self, template: bytes) -> bytes:
        return seal(template, self.counter.next(), _SIGNER, self._zero_tags)

    def check(
        self, prefix: bytes, data: bytes, source: tuple[str, int], now: float
    ) -> Freshness | Refusal:
        opened = open_tail(data)
        if opened is None:
            return Refusal.MISSING
        freshness = opened[0]
        window = self._windows.get(prefix)
        if window is None:
            window = self._windows[prefix] = ReplayWindow()
        if not window.accept(freshness):
            return Refusal.REPLAYED
        return freshness

    def note_address(self, prefix: bytes, source: tuple[str, int]) -> None:
        pass

    def counters(self) -> dict[str, int]:
        return {}
