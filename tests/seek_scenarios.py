"""The set-up shared by the seek scenarios on MemNet (tests/test_discovery_seek_answer.py,
test_discovery_seek_reach.py): a swarm formed under a link-loss geometry, then how long a
drone took to find a peer again after its return. Each scenario passes its own geometry;
times are virtual, never the host's."""

from __future__ import annotations

from collections.abc import Callable

from swarmd_lab.testing import Swarm, build_swarm

from swarmd.discovery.events import PeerDiscovered, PeerLost

# ``loss(now, src, dst)``: the share of ``src``'s frames that ``dst`` misses at virtual ``now``
Geometry = Callable[[float, int, int], float]


def formed_swarm(n: int, seed: int, loss: Geometry, t_cut: float) -> Swarm:
    """``n`` drones on MemNet under ``loss``, run until ``t_cut``, when all must have formed
    (the scenario's cut starts there)."""
    swarm = build_swarm(n, seed=seed)
    swarm.net.link_loss = lambda a, b: loss(swarm.net.now, a, b)
    swarm.run_until(t_cut)
    assert swarm.all_discovered(), "the swarm did not form before the scenario"
    return swarm


def found_again_s(swarm: Swarm, observer: int, peer: int, t_cut: float, t_back: float) -> float:
    """From ``t_back`` to ``observer``'s re-discovery of ``peer`` (inf: not by the run's end);
    ``observer`` must have lost ``peer`` between ``t_cut`` and ``t_back`` first."""
    name = swarm.bundle.participants[peer].name
    changes = [
        (t, isinstance(e, PeerDiscovered))
        for t, e in swarm.events[observer]
        if t >= t_cut and isinstance(e, PeerDiscovered | PeerLost) and e.name == name
    ]
    lost_first = changes and not changes[0][1] and changes[0][0] < t_back
    assert lost_first, f"drone {observer} did not lose drone {peer} in the cut"
    return next((t - t_back for t, found in changes if found), float("inf"))
