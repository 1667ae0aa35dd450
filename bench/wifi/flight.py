"""Flight scenarios for the ns-3 testbed (issue 20): scripted, seeded, pure.

A scenario is a list of waypoints ``(t, node, x, y, z)`` (seconds from the stacks' start
release, metres; each drone's stack starts ``start_offsets`` after it) that ns-3 applies
to each node's position (``bench/wifi/flight_cpp.py``), plus daemon events (reboots) the
harness performs (``bench/wifi/flight_run.py``) and the operator's commands it issues
through ``swarmctl`` (``CommandCue``, ``bench/wifi/flight_commands.py``). Moving nodes get
a waypoint every ``STEP_S``: the channel's log-distance loss, so every frame's
received power, SNR and loss, and the link files swarmd's link source reads, follow them.

*Ground truth* is the same propagation model evaluated on the same waypoints: a pair is
*in range* when the received power of the other's frames is at least ``RANGE_DBM`` (-82
dBm, the minimum RSSI of ns-3's default ``ThresholdPreambleDetectionModel``: below it a
frame is not even detected). With the testbed's 16 dBm, 46.68 dB at 1 m and exponent 3
that is ``range_m() = 51.4 m``. Deterministic loss, no fading: a pair in range hears the
group frames (DSSS 1 Mbps) except for collisions.

The five scenarios of issue 20 (N drones, uav1 = node 0 commands; the group is a grid at
``FORMATION_M`` after take-off; ``SETTLE_S`` for the initial discovery before anything moves):

- ``fly-out``: from a 1 m line (on the ground) to a grid at ``EDGE_M`` (neighbours near the
  edge of range, diagonals beyond it) and back;
- ``fade``: the last drone swings between ``FADE_NEAR_M`` and ``FADE_FAR_M`` from the
  formation (about 17 dB of RSSI) for ``FADE_S``, each swing's period drawn from the seed,
  ``FADE_PERIOD_S`` +- ``FADE_PERIOD_SPREAD_S`` (a drone at the edge of range does not swing
  with a clock's period; an exactly periodic fade locks onto a stack's fixed announcement
  period: docs/testbed.md, "An irregular fade"); ``period_spread_s=0`` is the old periodic one;
- ``split``: the second half flies ``SPLIT_OFFSET_M`` away for ``SPLIT_HOLD_S``, then back;
- ``reboot``: nobody moves; drone N/2's daemon is killed and restarted, once with its
  state dir kept and once with it deleted;
- ``blackout``: the commander flies out of everyone's range for ``BLACKOUT_S``.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

STEP_S: Final = 0.5  # a moving node's waypoint spacing (0.5 s at 10 m/s: 5 m, < 0.5 dB)
TX_POWER_DBM: Final = 16.0206  # the testbed channel's defaults (bench/wifi/channel.py)
REFERENCE_LOSS_DB: Final = 46.6777
EXPONENT: Final = 3.0
RANGE_DBM: Final = -82.0  # ns-3 ThresholdPreambleDetectionModel MinimumRssi
NOISE_DBM: Final = -94.0
SETTLE_S: Final = 30.0  # the paper's timing (Tmin 8, Tmax 20): discovery done well before
FORMATION_M: Final = 5.0
EDGE_M: Final = 45.0  # grid neighbours at -80.3 dBm: in range; diagonals (64 m) beyond it
FADE_NEAR_M: Final = 30.0
FADE_FAR_M: Final = 110.0  # 30*log10(110/30) = 16.9 dB of RSSI swing
FADE_PERIOD_S: Final = 8.0  # a swing's mean period (out and back)
FADE_PERIOD_SPREAD_S: Final = 2.0  # each swing's period ~ U(6, 10) s
FADE_HOLD_VALID_S: Final = 3.0  # the holds to the fading drone: at most half a swing
FADE_S: Final = 120.0
SPLIT_OFFSET_M: Final = 150.0
SPLIT_HOLD_S: Final = 60.0
MOVE_S: Final = 10.0  # flying out or back
BLACKOUT_S: Final = 30.0
TAIL_S: Final = 40.0  # after the last move: rediscovery must fit in it (lease 20 s)
# the staggered start (docs/testbed.md, "Staggered start"): each drone's stack starts
# U(0, stagger) after the release. Default: the longest fixed announcement period among the
# stacks (Cyclone DDS re-sends SPDP every lease - 2 s = 8 s, no jitter), so no two stacks'
# schedules stay aligned by the start alone
STAGGER_S: Final = 8.0
MAX_STAGGER_S: Final = 15.0  # every stack up at least 10 s before the take-off cue (25 s)


def rx_dbm(distance_m: float) -> float:
    """Received power at ``distance_m`` (ns-3 LogDistancePropagationLossModel, 1 m ref)."""
    d = max(distance_m, 1.0)
    return TX_POWER_DBM - REFERENCE_LOSS_DB - 10.0 * EXPONENT * math.log10(d)


def range_m() -> float:
    """The distance at which ``rx_dbm`` falls to ``RANGE_DBM``."""
    return float(10 ** ((TX_POWER_DBM - REFERENCE_LOSS_DB - RANGE_DBM) / (10.0 * EXPONENT)))


Position = tuple[float, float, float]


@dataclass(frozen=True)
class DaemonEvent:
    """``kill`` node's daemon (SIGKILL: no goodbye) or ``start`` it again; ``state``:
    ``kept`` or ``lost`` (the harness deletes its data-plane state dir first)."""

    t: float
    node: int
    action: str  # "kill" | "start"
    state: str = "kept"


@dataclass(frozen=True)
class CommandCue:
    """The operator's ``swarmctl <kind> --valid-for VALID_FOR_S --json`` on the commander at
    ``t``, to the drones ``only`` (node indices; empty: every drone); ``why``: the moment
    of the scenario it tests (issue 20, "Command authority in flight")."""

    t: float
    kind: str  # "takeoff" | "land" | "hold" | "abort"
    valid_for_s: float
    only: tuple[int, ...] = ()
    why: str = ""


# the first command of every scenario: vehicles ready (GPS fix within seconds of start)
# and discovery done (SETTLE_S) before it, so the take-off finds every drone ready
TAKEOFF_AT_S: Final = 25.0
TAKEOFF = CommandCue(TAKEOFF_AT_S, "takeoff", 5.0, why="take-off, everyone in range")


@dataclass(frozen=True)
class Scenario:
    name: str
    n: int
    seed: int
    duration_s: float
    waypoints: tuple[tuple[float, int, Position], ...]
    events: tuple[DaemonEvent, ...] = ()
    description: str = ""
    # [start, end) of the interesting part (the figure shades it; heal measures start there)
    phases: tuple[tuple[str, float, float], ...] = field(default=())
    commands: tuple[CommandCue, ...] = ()

    def positions_at(self, t: float) -> list[Position]:
        """Every node's position at ``t``: its last waypoint at or before ``t`` (the
        channel applies them as steps)."""
        pos: list[Position] = [(0.0, 0.0, 0.0)] * self.n
        for wt, i, p in sorted(self.waypoints):
            if wt > t:
                break
            pos[i] = p
        return pos

    def in_range(self, t: float) -> list[list[bool]]:
        """Ground truth at ``t``: ``m[i][j]`` whether i hears j's frames (symmetric)."""
        pos = self.positions_at(t)
        limit = range_m()
        return [
            [i != j and math.dist(pos[i], pos[j]) <= limit for j in range(self.n)]
            for i in range(self.n)
        ]

    def truth(self, step_s: float = STEP_S) -> list[tuple[float, list[list[bool]]]]:
        """``in_range`` every ``step_s`` from 0 to the end."""
        steps = int(self.duration_s / step_s) + 1
        return [(k * step_s, self.in_range(k * step_s)) for k in range(steps)]

    def waypoint_lines(self) -> str:
        """The channel's waypoint file: ``t i x y z`` per line."""
        return "".join(
            f"{t:.3f} {i} {x:.3f} {y:.3f} {z:.3f}\n" for t, i, (x, y, z) in self.waypoints
        )


def start_offsets(n: int, seed: int, stagger_s: float) -> tuple[float, ...]:
    """Each drone's start after the release (experiment seconds, ms), U(0, ``stagger_s``),
    from its own rng seeded by the run's ``seed`` (the scenario's draws stay as they are);
    ``stagger_s`` 0: every drone at the release (the lockstep start)."""
    if not 0.0 <= stagger_s <= MAX_STAGGER_S:
        raise ValueError(f"stagger {stagger_s} s not in [0, {MAX_STAGGER_S:g}] s")
    if stagger_s == 0.0:
        return (0.0,) * n
    rng = random.Random(f"start stagger {seed}")
    return tuple(round(rng.uniform(0.0, stagger_s), 3) for _ in range(n))


def grid(n: int, spacing_m: float, origin: Position = (0.0, 0.0, 10.0)) -> list[Position]:
    cols = math.ceil(math.sqrt(n))
    ox, oy, oz = origin
    return [(ox + (i % cols) * spacing_m, oy + (i // cols) * spacing_m, oz) for i in range(n)]


def _move(
    i: int, a: Position, b: Position, t0: float, t1: float
) -> list[tuple[float, int, Position]]:
    """Waypoints of a straight flight from a (at t0) to b (at t1), one every STEP_S."""
    steps = max(1, round((t1 - t0) / STEP_S))
    out = []
    for k in range(1, steps + 1):
        f = k / steps
        p = (a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f)
        out.append((t0 + (t1 - t0) * f, i, p))
    return out


def _jitter(points: Sequence[Position], rng: random.Random, m: float) -> list[Position]:
    """Seeded sub-metre placement noise: no two runs of a seed differ, two seeds do."""
    return [(x + rng.uniform(-m, m), y + rng.uniform(-m, m), z) for x, y, z in points]


def fly_out(n: int, seed: int) -> Scenario:
    rng = random.Random(seed)
    ground = _jitter([(float(i), 0.0, 0.0) for i in range(n)], rng, 0.1)
    edge = _jitter(grid(n, EDGE_M), rng, 0.5)
    out_at, back_at = SETTLE_S, SETTLE_S + MOVE_S + 40.0
    wps: list[tuple[float, int, Position]] = [(0.0, i, p) for i, p in enumerate(ground)]
    for i in range(n):
        wps += _move(i, ground[i], edge[i], out_at, out_at + 2 * MOVE_S)
        wps += _move(i, edge[i], ground[i], back_at, back_at + 2 * MOVE_S)
    end = back_at + 2 * MOVE_S
    return Scenario(
        "fly-out", n, seed, end + TAIL_S, tuple(sorted(wps)),
        description=f"1 m line -> {EDGE_M:.0f} m grid (diagonals out of range) and back",
        phases=(("out", out_at, back_at), ("back", back_at, end)),
        commands=(
            CommandCue(out_at, "takeoff", 5.0, why="take-off at the fly-out's start"),
            CommandCue(out_at + 2 * MOVE_S + 5.0, "hold", 10.0,
                       why="hold at the edge: the far corners beyond the commander's range"),
            CommandCue(end + 5.0, "land", 10.0, why="land once back on the line"),
        ),
    )  # fmt: skip


def fade(n: int, seed: int, period_spread_s: float = FADE_PERIOD_SPREAD_S) -> Scenario:
    """uav<n> swings out and back for ``FADE_S``; each swing's period is drawn from the
    scenario's rng, U(``FADE_PERIOD_S`` - ``period_spread_s``, ... + ``period_spread_s``).
    ``period_spread_s=0`` gives the exactly periodic fade (every ``FADE_PERIOD_S``) of the
    runs before the irregular one, waypoint for waypoint (``tests/test_flight_fade.py``)."""
    if not 0.0 <= period_spread_s < FADE_PERIOD_S:
        raise ValueError(f"fade: period_spread_s {period_spread_s} not in [0, {FADE_PERIOD_S})")
    rng = random.Random(seed)
    home = _jitter(grid(n - 1, FORMATION_M), rng, 0.3)
    cx = sum(p[0] for p in home) / len(home)
    cy = sum(p[1] for p in home) / len(home)
    near = (cx + FADE_NEAR_M, cy, 10.0)
    far = (cx + FADE_FAR_M, cy, 10.0)
    wps: list[tuple[float, int, Position]] = [(0.0, i, p) for i, p in enumerate(home)]
    wps.append((0.0, n - 1, near))
    t = SETTLE_S
    swings: list[tuple[float, float]] = []  # (start, period)
    while t < SETTLE_S + FADE_S:
        # drawn after the placement, so the placement is the periodic fade's for a seed
        period = rng.uniform(FADE_PERIOD_S - period_spread_s, FADE_PERIOD_S + period_spread_s)
        half = period / 2
        wps += _move(n - 1, near, far, t, t + half)
        wps += _move(n - 1, far, near, t + half, t + period)
        swings.append((t, period))
        t += period
    every = (
        f"{FADE_PERIOD_S - period_spread_s:g}-{FADE_PERIOD_S + period_spread_s:g}"
        if period_spread_s > 0
        else f"{FADE_PERIOD_S:g}"
    )
    # the holds go to the fading drone at four phases of its fifth swing (near, leaving,
    # far, coming back), by that swing's own period
    hold_at, hold_period = swings[4]
    return Scenario(
        "fade", n, seed, t + TAIL_S, tuple(sorted(wps)),
        description=f"uav{n} swings {FADE_NEAR_M:.0f}-{FADE_FAR_M:.0f} m from the group "
        f"(about {rx_dbm(FADE_NEAR_M) - rx_dbm(FADE_FAR_M):.0f} dB) every {every} s",
        phases=(("fade", SETTLE_S, t),),
        commands=(
            TAKEOFF,
            *(
                CommandCue(hold_at + quarter * hold_period, "hold", FADE_HOLD_VALID_S, (n - 1,),
                           why=f"hold to the fading drone {quarter * hold_period:.3g} s into "
                           "its swing")
                for quarter in (0.0, 0.25, 0.5, 0.75)
            ),
            CommandCue(t + 5.0, "land", 10.0, why="land after the fade"),
        ),
    )  # fmt: skip


def split(n: int, seed: int) -> Scenario:
    rng = random.Random(seed)
    home = _jitter(grid(n, FORMATION_M), rng, 0.3)
    away = [(x + SPLIT_OFFSET_M, y, z) for x, y, z in home]
    out_at = SETTLE_S
    back_at = out_at + MOVE_S + SPLIT_HOLD_S
    wps: list[tuple[float, int, Position]] = [(0.0, i, p) for i, p in enumerate(home)]
    for i in range(n // 2, n):
        wps += _move(i, home[i], away[i], out_at, out_at + MOVE_S)
        wps += _move(i, away[i], home[i], back_at, back_at + MOVE_S)
    return Scenario(
        "split", n, seed, back_at + MOVE_S + TAIL_S, tuple(sorted(wps)),
        description=f"uav{n // 2 + 1}..uav{n} fly {SPLIT_OFFSET_M:.0f} m away for "
        f"{SPLIT_HOLD_S:.0f} s and back",
        phases=(("split", out_at, back_at), ("heal", back_at, back_at + MOVE_S)),
        commands=(
            TAKEOFF,
            CommandCue(out_at + MOVE_S + 5.0, "hold", 10.0,
                       why="hold during the split, the far half still listed (lease running)"),
            CommandCue(back_at - 5.0, "hold", 30.0,
                       why="hold late in the split, valid past the heal"),
            CommandCue(back_at + MOVE_S + 10.0, "land", 10.0, why="land after the heal"),
        ),
    )  # fmt: skip


def reboot(n: int, seed: int) -> Scenario:
    rng = random.Random(seed)
    home = _jitter(grid(n, FORMATION_M), rng, 0.3)
    node = n // 2
    kept, lost = SETTLE_S + 10.0, SETTLE_S + 50.0
    events = (
        DaemonEvent(kept, node, "kill"),
        DaemonEvent(kept + 5.0, node, "start", "kept"),
        DaemonEvent(lost, node, "kill"),
        DaemonEvent(lost + 5.0, node, "start", "lost"),
    )
    return Scenario(
        "reboot", n, seed, lost + 5.0 + TAIL_S,
        tuple((0.0, i, p) for i, p in enumerate(home)), events,
        description=f"uav{node + 1}'s daemon killed for 5 s twice: state dir kept, then lost",
        phases=(("reboot, state kept", kept, kept + 5.0), ("reboot, state lost", lost, lost + 5)),
        commands=(
            TAKEOFF,
            CommandCue(kept + 1.0, "hold", 10.0, (node,),
                       why="hold to the rebooting drone while it is down, valid past its restart"),
            CommandCue(lost + 1.0, "hold", 3.0, (node,),
                       why="hold to the rebooting drone while down, expiring before it is back"),
            CommandCue(lost + 20.0, "land", 10.0, why="land after the reboots"),
        ),
    )  # fmt: skip


def blackout(n: int, seed: int) -> Scenario:
    rng = random.Random(seed)
    home = _jitter(grid(n, FORMATION_M), rng, 0.3)
    gone = (home[0][0] - 200.0, home[0][1], home[0][2])
    out_at = SETTLE_S
    back_at = out_at + 3.0 + BLACKOUT_S
    wps: list[tuple[float, int, Position]] = [(0.0, i, p) for i, p in enumerate(home)]
    wps += _move(0, home[0], gone, out_at, out_at + 3.0)
    wps += _move(0, gone, home[0], back_at, back_at + 3.0)
    return Scenario(
        "blackout", n, seed, back_at + 3.0 + TAIL_S, tuple(sorted(wps)),
        description=f"the commander out of everyone's range for {BLACKOUT_S:.0f} s",
        phases=(("blackout", out_at, back_at + 3.0),),
        commands=(
            TAKEOFF,
            CommandCue(out_at - 1.0, "land", 10.0, why="land just before the commander's blackout"),
            CommandCue(out_at + 15.0, "hold", 10.0, why="hold during the blackout"),
            CommandCue(back_at + 10.0, "hold", 10.0, why="hold after the commander is back"),
        ),
    )  # fmt: skip


SCENARIOS: Final[dict[str, Callable[[int, int], Scenario]]] = {
    "fly-out": fly_out,
    "fade": fade,
    "split": split,
    "reboot": reboot,
    "blackout": blackout,
}


def make(name: str, n: int, seed: int = 1) -> Scenario:
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; use one of: {', '.join(SCENARIOS)}")
    if n < 3:
        raise ValueError("a flight scenario needs at least 3 drones")
    return SCENARIOS[name](n, seed)


def of_run(run: Mapping[str, Any]) -> Scenario:
    """The scenario a run file was measured on, from its name, N and seed: ``make``, except a
    fade run from before the irregular fade, whose recorded waypoints are the periodic
    fade's (``period_spread_s=0``): its truth must be the one its drones flew."""
    scenario = make(run["scenario"], run["n"], run["seed"])
    recorded = run.get("waypoints")
    if run["scenario"] != "fade" or recorded is None or _recorded(scenario) == recorded:
        return scenario
    periodic = fade(run["n"], run["seed"], period_spread_s=0.0)
    return periodic if _recorded(periodic) == recorded else scenario


def _recorded(scenario: Scenario) -> list[list[Any]]:
    """The waypoints as a run file holds them (``flight_run.assemble``)."""
    return [[t, i, *p] for t, i, p in scenario.waypoints]
