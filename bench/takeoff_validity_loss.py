"""What bounding every ARM and NAV_TAKEOFF frame by the command's validity costs an honest
take-off on a lossy link (docs/dataplane.md, "Validity at the vehicle"; session 18).

    .venv/bin/python -m bench.takeoff_validity_loss [RUNS] [--losses 0,0.1,0.3] [--left 3,1.2]
        [--backends mavlink,xrce]

RUNS take-offs (default 200, seeds 0..RUNS-1) per loss rate and validity left when the
request reaches the vehicle (``--left``, seconds: 3 is the default TAKEOFF validity on a
link that delivers at once, 1.2 what is left after the 1.8 s the data plane's repairs take
at worst at 30 % loss, docs/dataplane.md "Numbers"). Every message is lost with the loss
probability each way once the vehicle is ready: MAVLink against the vehicle simulator
(``VirtualLink``, as ``bench/takeoff_loss.py``) and XRCE datagrams against the PX4 1.16
stand-in (the reliable stream repairs; ``bench/xrce_takeoff_loss.py``). Per rule: how the
take-offs ended. "bounded" is this build (``not_after`` on every frame); "start only" is
session 17 (``not_after`` checked at the start alone), which also counts the take-offs
that put an ARM or NAV_TAKEOFF on the wire at or after the validity end ("late frames",
with the latest; over XRCE counted where PX4 reads it: a frame sent in time can wait in
PX4's reliable input stream behind an earlier message until that one is repaired).
A reading, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
from collections import Counter

from bench.takeoff_loss import lossy_link
from bench.xrce_takeoff_loss import LossyEdge
from swarmd.px4.constants import MavCmd
from swarmd.px4.messages import VehicleCommand
from swarmd.px4.takeoff import TakeoffFailed, TakeoffSequence
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleRequest


def _motion(cmd: VehicleCommand) -> bool:
    arm = cmd.command == MavCmd.COMPONENT_ARM_DISARM and cmd.params[0] == 1.0
    return arm or cmd.command == MavCmd.NAV_TAKEOFF


def mavlink_one(seed: int, loss: float, left: float, bounded: bool) -> tuple[str, float | None]:
    """The outcome's code, and how long after the end the last ARM or NAV_TAKEOFF left
    (None: none at or after it)."""
    link = lossy_link(seed, loss)
    late: float | None = None
    drop = link.drop
    not_after = link.now + left

    def watch(msg: object, direction: str, now: float) -> bool:
        nonlocal late
        motion = direction == "down" and isinstance(msg, VehicleCommand) and _motion(msg)
        if motion and now >= not_after:
            late = now - not_after
        return drop is not None and drop(msg, direction, now)  # type: ignore[arg-type]

    link.drop = watch
    seq = TakeoffSequence(link.state, 5.0, not_after=not_after if bounded else None)
    link.start(seq)
    link.run_until(link.now + 30.0, stop=lambda: seq.outcome is not None)
    out = seq.outcome
    code = out.reason.value if isinstance(out, TakeoffFailed) else "succeeded"
    return code, late


def xrce_one(seed: int, loss: float, left: float, bounded: bool) -> tuple[str, float | None]:
    """As ``mavlink_one``, the frames counted when they reach PX4's vehicle_command."""
    edge = LossyEdge(seed, "1.16")
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    edge.loss = loss
    not_after = edge.clock.now + left
    request = VehicleRequest(1, TaskKind.TAKEOFF, 5.0, None, not_after if bounded else None)
    edge.core_driver.call(lambda now: edge.core.request(request, now))
    end = edge.clock.now + 20.0
    done: TaskFinished | None = None
    while (done := edge.finished(1)) is None and edge.clock.now < end:
        edge.run(edge.clock.now + 0.05)
    lates = [
        t - not_after
        for t, c, p1 in edge.px4_commands
        if t >= not_after
        and (c == MavCmd.NAV_TAKEOFF or (c == MavCmd.COMPONENT_ARM_DISARM and p1 == 1))
    ]
    late = max(lates, default=None)
    if done is None:
        return "never_ended", late
    out = done.outcome
    code = out.reason.value if isinstance(out, TakeoffFailed) else "succeeded"
    return code, late


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("runs", nargs="?", type=int, default=200)
    parser.add_argument("--losses", default="0,0.1,0.3")
    parser.add_argument("--left", default="3,1.2")
    parser.add_argument("--backends", default="mavlink,xrce")
    args = parser.parse_args()
    backends = (("mavlink", mavlink_one), ("xrce 1.16", xrce_one))
    for backend, one in (b for b in backends if b[0].split()[0] in args.backends):
        for loss in (float(x) for x in args.losses.split(",")):
            for left in (float(x) for x in args.left.split(",")):
                for name, bounded in (("bounded", True), ("start only", False)):
                    codes: Counter[str] = Counter()
                    lates: list[float] = []
                    for seed in range(args.runs):
                        code, late = one(seed, loss, left, bounded)
                        codes[code] += 1
                        lates += [] if late is None else [late]
                    ended = ", ".join(f"{k} {v}" for k, v in sorted(codes.items()))
                    worst = f", the latest {max(lates):.3f} s after the end" if lates else ""
                    print(
                        f"{backend:9s} loss {loss:.0%} left {left:g} s {name:10s}: {ended}; "
                        f"late frames in {len(lates)}{worst}",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
