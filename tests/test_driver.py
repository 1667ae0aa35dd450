"""The one asyncio driver: what it promises any sans-IO core (swarmd/driver.py)."""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Any

from swarmd.dataplane import DataPlane
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.driver import Driver, SansIOCore
from swarmd.px4.vehicle import VehicleCore
from swarmd.swarm.core import SwarmCore


class Core:
    """A core that records its inputs and emits what the test queues."""

    def __init__(self) -> None:
        self.inputs: list[tuple[str, Any, float]] = []
        self.out: list[str] = []
        self.events: deque[str] = deque()
        self.deadline: float | None = None
        self.raise_on: str | None = None

    def receive_datagram(self, data: str, source: Any, now: float) -> None:
        self.inputs.append(("datagram", data, now))
        if data == self.raise_on:
            raise RuntimeError("a bug in the core")
        self.out.append(f"echo {data}")
        self.events.append(f"got {data}")

    def handle_timer(self, now: float) -> None:
        self.inputs.append(("timer", None, now))
        self.deadline = None

    def datagrams_to_send(self) -> list[str]:
        out, self.out = self.out, []
        return out

    def get_timer(self) -> float | None:
        return self.deadline

    def next_event(self) -> str | None:
        return self.events.popleft() if self.events else None


def _cores_speak_the_protocol(
    discovery: DiscoveryEngine, plane: DataPlane, swarm: SwarmCore, vehicle: VehicleCore
) -> list[SansIOCore[Any, Any, Any]]:
    """Checked by mypy --strict (never called): every core the daemon drives fits."""
    return [discovery, plane, swarm, vehicle]


def test_input_sends_then_dispatches_then_rearms() -> None:
    async def main() -> None:
        core = Core()
        sent: list[str] = []
        seen: list[str] = []
        driver = Driver(core, transmit=sent.append, on_event=seen.append, name="t")
        core.deadline = driver.loop.time() + 3600.0
        driver.datagram_received("a", ("h", 1))
        assert sent == ["echo a"] and seen == ["got a"]
        assert driver.deadline == core.deadline
        driver.close()

    asyncio.run(main())


def test_a_handler_calling_back_in_does_not_recurse_and_keeps_order() -> None:
    async def main() -> None:
        core = Core()
        sent: list[str] = []
        seen: list[str] = []
        driver: Driver[str, str, str]

        def on_event(event: str) -> None:
            seen.append(event)
            if event == "got a":
                driver.datagram_received("b", None)  # a handler answering at once
                assert seen == ["got a"]  # not handled inside this call: no recursion

        driver = Driver(core, transmit=sent.append, on_event=on_event, name="t")
        driver.datagram_received("a", None)
        assert seen == ["got a", "got b"] and sent == ["echo a", "echo b"]
        driver.close()

    asyncio.run(main())


def test_early_wake_gets_the_deadline_not_an_earlier_now() -> None:
    """asyncio may fire a timer a little before its deadline; the core must see a ``now``
    at or past the deadline it asked for, or it would ask for the same deadline again."""

    async def main() -> None:
        core = Core()
        driver = Driver(core, transmit=lambda _: None, on_event=lambda _: None, name="t")
        core.deadline = driver.loop.time() + 3600.0  # far ahead: the test fires it early
        driver.drain()
        driver._fire()  # noqa: SLF001 - the early wake, without waiting an hour
        assert core.inputs == [("timer", None, core.inputs[0][2])]
        assert core.inputs[0][2] >= driver.loop.time() + 3599.0
        driver.close()

    asyncio.run(main())


def test_the_timer_fires_and_is_rearmed_only_on_change() -> None:
    async def main() -> None:
        core = Core()
        driver = Driver(core, transmit=lambda _: None, on_event=lambda _: None, name="t")
        core.deadline = driver.loop.time()
        driver.drain()
        handle = driver._timer  # noqa: SLF001
        driver.drain()  # same deadline: the same TimerHandle
        assert driver._timer is handle  # noqa: SLF001
        for _ in range(100):
            if core.inputs:
                break
            await asyncio.sleep(0)
        assert [kind for kind, _, _ in core.inputs] == ["timer"]
        assert driver.deadline is None
        driver.close()

    asyncio.run(main())


def test_a_raising_core_is_counted_and_the_driver_goes_on() -> None:
    async def main() -> None:
        core = Core()
        core.raise_on = "boom"
        errors: list[int] = []
        sent: list[str] = []
        driver = Driver(
            core,
            transmit=sent.append,
            on_event=lambda _: None,
            name="t",
            on_core_error=lambda: errors.append(1),
        )
        driver.datagram_received("boom", None)
        driver.datagram_received("ok", None)
        assert driver.counters["core_errors"] == 1 and errors == [1]
        assert sent == ["echo ok"]
        driver.close()
        driver.datagram_received("late", None)
        assert [d for _, d, _ in core.inputs] == ["boom", "ok"]

    asyncio.run(main())


def test_a_closed_driver_is_inert() -> None:
    """After ``close`` nothing reaches the core: no datagram, no timer, no call (its action
    does not run, the answer is None), and nothing it still queues is sent."""

    async def main() -> None:
        core = Core()
        sent: list[str] = []
        seen: list[str] = []
        driver = Driver(core, transmit=sent.append, on_event=seen.append, name="t")
        assert driver.call(lambda now: core.receive_datagram("before", None, now)) is None
        assert driver.call(lambda now: 7) == 7
        core.deadline = driver.loop.time() + 0.01
        driver.drain()
        driver.close()
        ran: list[float] = []

        def action(now: float) -> int:
            ran.append(now)
            core.out.append("queued after close")
            return 1

        assert driver.call(action) is None
        driver.datagram_received("late", None)
        await asyncio.sleep(0.05)  # the armed timer's deadline passes: it was cancelled
        assert ran == []
        assert [(kind, data) for kind, data, _ in core.inputs] == [("datagram", "before")]
        assert sent == ["echo before"] and seen == ["got before"]
        assert driver.deadline is None

    asyncio.run(main())


def test_a_batch_is_received_at_one_now_and_drained_once() -> None:
    """The daemon's batched read (docs/security.md, "Flood"): every datagram reaches the
    core in order at the same ``now``, a raising one is counted and the rest still go in,
    and the outputs leave in one drain after the batch (not one per datagram)."""

    async def main() -> None:
        core = Core()
        core.raise_on = "boom"
        sent: list[str] = []
        drains: list[int] = []
        driver = Driver(core, transmit=sent.append, on_event=lambda _: None, name="t")
        inner = driver.drain

        def counted_drain() -> None:
            drains.append(len(core.inputs))
            inner()

        driver.drain = counted_drain  # type: ignore[method-assign]
        driver.datagrams_received([("a", ("h", 1)), ("boom", ("h", 1)), ("c", ("h", 2))])
        assert [d for _, d, _ in core.inputs] == ["a", "boom", "c"]
        assert len({now for _, _, now in core.inputs}) == 1
        assert drains == [3]  # once, after the whole batch
        assert sent == ["echo a", "echo c"] and driver.counters["core_errors"] == 1
        driver.close()
        driver.datagrams_received([("late", None)])
        assert len(core.inputs) == 3

    asyncio.run(main())
