"""The testbed's fade on virtual time (``bench/flight_fade.py``: MemNet cut by the ns-3
scenario's own truth, each drone's Q from eq. 2 on the positions): a lease that ends just
as the fading drone comes back into range is followed by a frame that finds the pair again
within that in-range window (docs/discovery.md, "A lease's end announces us").

The two cases are the clean channel's slow ones before that rule (``python
bench/flight_fade.py --prompt-readiness --verbose``): at N = 10, seed 3, uav4 and uav7 lost
the fading uav10 at 46.2 s, in range, and found it again 24 s later; at N = 20, seed 9,
uav20 lost 15 peers at 45.77 s, in range, and found them 17-48 s later. Each in-range window
is 1.5-2.5 s of every 8 s swing.
"""

from __future__ import annotations

import pytest

from bench import flight_fade
from bench.wifi import flight, flight_measures


@pytest.mark.parametrize(("n", "seed"), [(10, 3), (20, 9)])
def test_a_lease_ending_in_range_is_found_again_in_the_same_window(n: int, seed: int) -> None:
    result = flight_fade.run(
        n, seed, prompt_readiness=True, loss=0.0, flight=flight, measures=flight_measures
    )
    assert result["losses"]  # the case is still there: leases end as the drone returns
    assert result["lost_reports"]["false"] == 0
    # every loss, from the peer's return into range (or the loss, if later) to its
    # re-discovery: within the window, not a whole 8 s swing later
    assert max(result["back_to_found"]) <= 2.0
