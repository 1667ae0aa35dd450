"""The testbed's fade on virtual time (``bench/flight_fade.py``: MemNet cut by the ns-3
scenario's own truth, each drone's Q from eq. 2 on the positions): a lease that ends just
as the fading drone comes back into range is followed by a frame that finds the pair again
within that in-range window (docs/discovery.md, "A lease's end announces us").

The two cases are the clean channel's slow ones before that rule (``python
bench/flight_fade.py --prompt-readiness --verbose``): at N = 10, seed 3, uav4 and uav7 lost
the fading uav10 at 46.2 s, in range, and found it again 24 s later; at N = 20, seed 9,
uav20 lost 15 peers at 45.77 s, in range, and found them 17-48 s later. Each in-range window
is 1.5-2.5 s of every 8 s swing. Both cases are of the exactly periodic fade
(``flight.fade(..., period_spread_s=0.0)``, ``--periodic``), which the flight runs used before
the irregular one (docs/testbed.md, "An irregular fade"); the periodic shape is pinned here
waypoint for waypoint, and the irregular fade's swings are checked for their bounds.
"""

from __future__ import annotations

import hashlib
import math

import pytest

from bench import flight_fade
from bench.wifi import flight, flight_measures


@pytest.mark.parametrize(("n", "seed"), [(10, 3), (20, 9)])
def test_a_lease_ending_in_range_is_found_again_in_the_same_window(n: int, seed: int) -> None:
    result = flight_fade.run(
        n,
        seed,
        prompt_readiness=True,
        loss=0.0,
        flight=flight,
        measures=flight_measures,
        periodic=True,
    )
    assert result["losses"]  # the case is still there: leases end as the drone returns
    assert result["lost_reports"]["false"] == 0
    # every loss, from the peer's return into range (or the loss, if later) to its
    # re-discovery: within the window, not a whole 8 s swing later
    assert max(result["back_to_found"]) <= 2.0


# sha256 of ``waypoint_lines()`` of the periodic fade as flight.fade drew it before the
# irregular fade existed (commit b1e8252, ``flight.make("fade", n, seed)``)
PERIODIC_WAYPOINTS_SHA256 = {
    (10, 1): "29297e7b48148a159d5010a7310f9c9f1ae812ee753bac39737d680515823fea",
    (20, 9): "52bdb7aafa6a91b283a55b0e1e59bd76133e824e45156ab637c8092a517fdee7",
}


@pytest.mark.parametrize(("n", "seed"), sorted(PERIODIC_WAYPOINTS_SHA256))
def test_the_periodic_fade_is_the_old_one_byte_for_byte(n: int, seed: int) -> None:
    s = flight.fade(n, seed, period_spread_s=0.0)
    digest = hashlib.sha256(s.waypoint_lines().encode()).hexdigest()
    assert digest == PERIODIC_WAYPOINTS_SHA256[(n, seed)]
    assert s.duration_s == flight.SETTLE_S + flight.FADE_S + flight.TAIL_S
    assert s.description.endswith("every 8 s")
    holds = [c.t for c in s.commands if c.kind == "hold"]
    assert holds == [62.0, 64.0, 66.0, 68.0]  # the fifth swing at 0, 2, 4, 6 s


def _swings(s: flight.Scenario) -> list[tuple[float, float]]:
    """(start, period) of every swing: the fading drone's arrivals back at its near point."""
    fading = s.n - 1
    near = next(p for t, i, p in s.waypoints if i == fading and t == 0.0)
    backs = [flight.SETTLE_S] + [
        t for t, i, p in s.waypoints if i == fading and t > 0 and math.dist(p, near) < 1e-6
    ]
    return [(a, b - a) for a, b in zip(backs, backs[1:], strict=False)]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_fade_swings_irregularly_within_6_to_10_s(seed: int) -> None:
    s = flight.make("fade", 10, seed)
    swings = _swings(s)
    periods = [p for _, p in swings]
    assert len(swings) >= flight.FADE_S / 10.0  # the whole fade, swing by swing
    assert all(6.0 - 1e-9 <= p <= 10.0 + 1e-9 for p in periods), periods
    assert len({round(p, 3) for p in periods}) == len(periods)  # no two swings alike
    assert swings[-1][0] < flight.SETTLE_S + flight.FADE_S <= swings[-1][0] + periods[-1]
    assert s.description.endswith("every 6-10 s")
    # the holds: at four phases of the fifth swing, by its own period
    start, period = swings[4]
    holds = [c.t for c in s.commands if c.kind == "hold"]
    assert holds == pytest.approx([start + f * period for f in (0.0, 0.25, 0.5, 0.75)])
    assert all(c.only == (9,) and c.valid_for_s <= 6.0 / 2 for c in s.commands if c.kind == "hold")
    assert flight.make("fade", 10, seed) == s  # seeded: the same seed, the same fade
    assert _swings(flight.make("fade", 10, seed + 10)) != swings


def test_a_periodic_fade_swings_every_8_s() -> None:
    periods = [p for _, p in _swings(flight.fade(10, 1, period_spread_s=0.0))]
    assert periods == pytest.approx([8.0] * 15)
    with pytest.raises(ValueError, match="period_spread_s"):
        flight.fade(10, 1, period_spread_s=8.0)


def test_a_run_file_of_the_periodic_fade_is_measured_on_the_periodic_fade() -> None:
    # the run files before the irregular fade hold the periodic waypoints: their truth (and
    # so their re-measure and figure) must be that fade's, not the seed's irregular one
    periodic, irregular = flight.fade(10, 1, period_spread_s=0.0), flight.make("fade", 10, 1)
    assert periodic.waypoints != irregular.waypoints
    for s in (periodic, irregular):
        run = {"scenario": "fade", "n": 10, "seed": 1}
        run["waypoints"] = [[t, i, *p] for t, i, p in s.waypoints]
        assert flight.of_run(run) == s
    assert flight.of_run({"scenario": "fade", "n": 10, "seed": 1}) == irregular


def test_the_fader_s_losses_are_counted_with_their_largest_burst() -> None:
    losses: list[tuple[float, int, int, float | None]] = [
        (45.2, 19, 1, 45.3),
        (104.58, 19, 2, 104.9),
        (104.58, 19, 3, None),
        (104.58, 19, 4, 105.1),
        (104.58, 0, 19, 105.0),  # another observer's loss: not the fader's
        (130.58, 19, 5, 130.8),
    ]
    assert flight_fade.fader_losses(losses, 19) == (5, 3, 104.58)
    assert flight_fade.fader_losses(losses, 7) == (0, 0, None)


def test_the_fader_s_burst_of_losses_is_the_commander_s_vouch_running_out() -> None:
    # the irregular fade of the N = 20 runs (seed 1), engines seed 2: the fading drone's leases
    # of the members rest on the commander's vouches (lease - w - 0.5 = 17 s from the last
    # one it heard); when no vouch lands in its short windows in the commander's range, the
    # members it listed are lost together (docs/flight-history.md, "The fading drone's losses
    # at N = 20 (session 9)")
    result = flight_fade.run(
        20, 2, prompt_readiness=True, loss=0.0, flight=flight, measures=flight_measures
    )
    _, burst, burst_at = flight_fade.fader_losses(result["losses"], 19)
    assert burst >= 13 and burst_at is not None
    last_heard = max(t for t in result["commander_to_fader"] if t < burst_at)
    assert burst_at - last_heard == pytest.approx(17.0, abs=0.05)
    assert result["lost_reports"]["false"] == 0
