"""How fast a local user can guess the XRCE client key (docs/security.md, "XRCE's
key, guessed"): wrong-key CREATE_CLIENTs against swarmd's bound agent, bounded in count and time,
loopback only. Prints markdown.

    .venv/bin/python bench/xrce_key_guess.py [--count 200000] [--seconds 5] [--ports 64]

1. the sans-IO agent alone: ``--count`` CREATE_CLIENTs of distinct wrong keys from ``--ports``
   source ports, fed as fast as the core takes them (no socket): the core's ceiling;
2. the sans-IO agent on virtual time: 1000 a second for 10 virtual minutes: the long-run
   rate, where a budget's burst no longer counts;
3. real sockets: swarmd's XRCE backend (the daemon's agent) on a free 127.0.0.1 port, the
   attacker a thread sending distinct wrong keys from ``--ports`` sockets as fast as it can,
   at most ``--count`` datagrams or ``--seconds``; then what the agent checked, what it
   answered and what the attacker learnt from the answers.

Key checks per second are the agent's, from its own counters: ``refused`` (each a key it
compared: ``wrong_key`` or ``vehicle_alive``) against ``over_budget`` (dropped unchecked; only
with a check budget). The expected time to guess is half the generated key space (2^31 - 1,
``swarmd.px4.xrce_key.GENERATED_MAX``) over the checked rate. 2 shared cores: the rates move
with the box's load; the checks per datagram and the answers per check do not.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import sys
import time
from collections.abc import Mapping
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd.px4.xrce_backend import XrceBackend  # noqa: E402
from swarmd.px4.xrce_key import GENERATED_MAX  # noqa: E402
from swarmd.xrce.agent import XrceAgent  # noqa: E402
from swarmd.xrce.message import CreateClient, Header, decode_message, encode_message  # noqa: E402

VEHICLE_KEY = 0x0BAD_CAFE
YEAR_S = 365.25 * 86400


def create_client(key: int) -> bytes:
    return encode_message(Header(0x80, 0, 0), [CreateClient(key.to_bytes(4, "big"), 0x81)])


def wrong_keys(count: int) -> list[bytes]:
    return [create_client(k) for k in range(1, count + 1) if k != VEHICLE_KEY][:count]


def checked(refused: Mapping[str, int]) -> int:
    return sum(n for why, n in refused.items() if why in ("wrong_key", "vehicle_alive"))


def expected_time(rate_per_s: float) -> str:
    if rate_per_s <= 0:
        return "never"
    seconds = (GENERATED_MAX / 2) / rate_per_s
    if seconds >= YEAR_S:
        return f"{seconds / YEAR_S:.1f} years"
    return f"{seconds / 3600:.1f} hours"


def table_row(
    path: str,
    sent: int,
    seconds: str,
    refused: Mapping[str, int],
    answers: str,
    elapsed_s: float,
    rate_digits: int = 0,
) -> str:
    """One row of the table ``main`` prints: the keys the agent checked in ``elapsed_s``
    give the rate, and the rate the expected time to guess."""
    n = checked(refused)
    rate = n / elapsed_s
    return (
        f"| {path} | {sent} | {seconds} | {n} | {refused.get('over_budget', 0)} "
        f"| {answers} | {rate:,.{rate_digits}f} | {expected_time(rate)} |"
    )


def answered(agent: XrceAgent) -> int:
    """What the sans-IO agent sent back since the last call; its events dropped."""
    answers = len(agent.datagrams_to_send())
    while agent.next_event() is not None:
        pass
    return answers


def sans_io(count: int, ports: int) -> str:
    agent = XrceAgent(expected_key=VEHICLE_KEY.to_bytes(4, "big"))
    datagrams = wrong_keys(count)
    answers = 0
    t0 = time.perf_counter()
    for i, data in enumerate(datagrams):
        now = time.perf_counter() - t0
        agent.receive_datagram(data, ("127.0.0.1", 40000 + i % ports), now)
        answers += answered(agent)
    elapsed = time.perf_counter() - t0
    refused = dict(agent.refused)
    return table_row(
        "sans-IO core", len(datagrams), f"{elapsed:.2f}", refused, str(answers), elapsed
    )


def virtual_minutes(minutes: int, per_s: int, ports: int) -> str:
    """The long run, on virtual time: ``per_s`` wrong keys a second for ``minutes``."""
    agent = XrceAgent(expected_key=VEHICLE_KEY.to_bytes(4, "big"))
    key = 0
    answers = 0
    duration_s = minutes * 60
    for tick in range(duration_s * 100):  # 10 ms steps
        now = tick / 100
        for _ in range(per_s // 100):
            key += 1
            agent.receive_datagram(create_client(key), ("127.0.0.1", 40000 + key % ports), now)
        answers += answered(agent)
    path = f"sans-IO core, {minutes} virtual minutes at {per_s}/s"
    refused = dict(agent.refused)
    return table_row(
        path, key, f"{duration_s} (virtual)", refused, str(answers), duration_s, rate_digits=2
    )


def attacker(
    port: int, datagrams: list[bytes], ports: int, seconds: float, out: dict[str, int]
) -> None:
    """Send ``datagrams`` round-robin from ``ports`` sockets until done or ``seconds``; count
    the answers (each a STATUS_AGENT) and their statuses."""
    socks = []
    for _ in range(ports):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        socks.append(s)
    deadline = time.monotonic() + seconds
    sent = answers = 0
    statuses: dict[str, int] = {}

    def drain() -> None:
        nonlocal answers
        for s in socks:
            while True:
                try:
                    data = s.recv(2048)
                except BlockingIOError:
                    break
                answers += 1
                sub = decode_message(data).submessages[0]
                status = f"status_{getattr(sub, 'status', '?'):#04x}"
                statuses[status] = statuses.get(status, 0) + 1

    for i, data in enumerate(datagrams):
        if i % 256 == 0:
            drain()
            if time.monotonic() > deadline:
                break
        try:
            socks[i % ports].sendto(data, ("127.0.0.1", port))
            sent += 1
        except BlockingIOError:
            pass
    time.sleep(0.5)  # the agent's last answers
    drain()
    for s in socks:
        s.close()
    out.update({"sent": sent, "answers": answers, **statuses})


async def real_sockets(count: int, seconds: float, ports: int) -> str:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1, expected_key=VEHICLE_KEY)

    await backend.start(lambda obs, now: None)
    out: dict[str, int] = {}
    datagrams = wrong_keys(count)
    t0 = time.perf_counter()
    # the agent's loop runs here; the attacker blocks nothing of it (its own thread)
    await asyncio.to_thread(attacker, port, datagrams, ports, seconds, out)
    elapsed = time.perf_counter() - t0 - 0.5  # the attacker's final wait is not attack time
    stats = backend.stats()
    await backend.close()
    detail = ", ".join(f"{k} {v}" for k, v in sorted(out.items()) if k.startswith("status"))
    return table_row(
        f"real sockets ({stats['datagrams_in']} of {out['sent']} sent reached the agent)",
        out["sent"],
        f"{elapsed:.2f}",
        stats["refused"],
        f"{out['answers']} ({detail or 'none'})",
        elapsed,
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200_000)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--ports", type=int, default=64)
    args = parser.parse_args()
    count = min(args.count, 1_000_000)  # bounded whatever the flag says
    seconds = min(args.seconds, 30.0)
    print(
        f"## Wrong-key CREATE_CLIENTs against the bound agent ({count} at most, "
        f"{seconds:g} s at most, {args.ports} source ports, loopback)\n"
    )
    print(
        "| path | datagrams | seconds | keys checked | dropped unchecked | answers "
        "| checks/s | expected time to guess (2^30 tries) |\n|---|---:|---:|---:|---:|---|---:|---|"
    )
    print(sans_io(count, args.ports))
    print(virtual_minutes(10, 1000, args.ports))
    print(asyncio.run(real_sockets(count, seconds, args.ports)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
