"""What the engine shows when asked: typed views of its peers and the JSON forms of
``swarmctl status --json`` (schema: docs/operations.md).

Evaluated when asked, never per datagram (``tests/test_daemon_loopback.py``: a datagram flood
builds no status), and pure: nothing here changes the engine's state.
"""

from __future__ import annotations

from typing import Any, Final

from swarmd.discovery.config import Timing
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.timers import WindowRate
from swarmd.discovery.views import ForeignView, PeerView

_DISCOVERED: Final = PeerState.DISCOVERED


def peer_view(p: Peer) -> PeerView:
    """The read-only view of one bundle peer."""
    discovered = p.state is _DISCOVERED
    return PeerView(
        name=p.participant.name,
        index=p.index,
        guid_prefix=p.participant.guid_prefix,
        state=p.state,
        last_heard=p.last_heard,
        locator=p.target(),
        metatraffic_unicast_locators=p.metatraffic_locators,
        default_unicast_locators=p.default_locators,
        matches=(p.matches or ()) if discovered else (),
        lists_me=discovered and p.lists_me,
        lease_s=p.lease_s,
        link_quality_permille=p.link_quality_permille,
        times_discovered=p.times_discovered,
        epoch=p.epoch,
    )


def link_json(q: float, link: LinkSample | None) -> dict[str, Any]:
    """Our link quality and, once read, where it came from."""
    if link is None:
        return {"q": round(q, 3), "snr_db": None, "source": None}
    return {"q": round(q, 3), "snr_db": link.snr_db, "source": link.source}


def peer_json(p: PeerView, now: float) -> dict[str, Any]:
    """One row of ``peers``."""
    return {
        "name": p.name,
        "index": p.index,
        "state": str(p.state),
        "guid": f"{p.guid_prefix}:1c1",
        "last_heard_s": None if p.last_heard is None else round(now - p.last_heard, 3),
        "locator": None if p.locator is None else f"udp/{p.locator[0]}:{p.locator[1]}",
        "matched_endpoints": len(p.matches),
        "lists_me": p.lists_me,
        "epoch": p.epoch,  # its boot epoch (signed): a jump means it restarted
    }


def foreign_json(e: ForeignView) -> dict[str, Any]:
    """One row of ``foreign``."""
    return {
        "guid": f"{e.guid_prefix}:1c1",
        "vendor": e.vendor,
        "name": e.name,
        "reason": str(e.reason),
    }


def timing_json(timing: Timing, *, renewal_period_s: float, lease_s: float) -> dict[str, Any]:
    """The resolved timing (and where each value came from), with the renewal period and
    the lease we advertise now."""
    return {
        "t_min_s": timing.t_min_s,
        "t_max_s": timing.t_max_s,
        "lease_s": timing.lease_s,
        "sources": dict(timing.sources),
        "renewal_period_s": round(renewal_period_s, 3),
        "advertised_lease_s": round(lease_s, 3),
    }


def rates_json(
    now: float,
    *,
    renewals_sent: WindowRate,
    vouches_sent: WindowRate,
    vouches_received: WindowRate,
) -> dict[str, Any]:
    """What we sent and took per second over the last window (issue 20: whether the
    renewal and vouch rates follow the link quality), with the totals since start."""
    return {
        "window_s": renewals_sent.window_s,
        "renewals_sent_per_s": round(renewals_sent.per_s(now), 4),
        "vouches_sent_per_s": round(vouches_sent.per_s(now), 4),
        "vouches_received_per_s": round(vouches_received.per_s(now), 4),
        "renewals_sent": renewals_sent.total,
        "vouches_sent": vouches_sent.total,
        "vouches_received": vouches_received.total,
    }
