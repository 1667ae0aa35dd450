"""A pytest plugin that counts what members decided for the commands of other nodes during a
test run: run, or refused (``expired``, ``memory_lost``), per test (docs/security-history.md, "This
morning's defences reviewed (session 11)": does the rule that a life runs only its own
commands refuse an honest command in the virtual-time flight tests?).

    PYTHONPATH=.:lab:bench nice -n 19 .venv/bin/pytest -q -p refusal_tally \\
        tests/test_cmd_in_flight.py tests/test_swarm_core.py ...

It wraps ``Member._may_run`` (``swarmd/swarm/member.py``: the one place a member judges a
command from another node) and prints, after the run, how many commands were judged, how
many ran, and each refusal with its reason, detail and test. Review tooling: it changes no
decision.
"""

from __future__ import annotations

import os
from collections import Counter
from typing import Any

from swarmd.dataplane.types import Command, CommandKind
from swarmd.swarm import member
from swarmd.swarm.events import CommandBeforeLife, CommandExpired

TALLY: Counter[str] = Counter()
_may_run = member.Member._may_run


def _counted(
    self: member.Member, commander: str, command: Command, kind: CommandKind, now: float
) -> bool:
    ran = _may_run(self, commander, command, kind, now)
    TALLY["judged"] += 1
    if ran:
        TALLY["ran"] += 1
        return ran
    refusals = [e for e in self._events if isinstance(e, CommandExpired | CommandBeforeLife)]
    event = refusals[-1]
    reason = "memory_lost" if isinstance(event, CommandBeforeLife) else "expired"
    test = os.environ.get("PYTEST_CURRENT_TEST", "?").split(" ")[0]
    TALLY[f"refused {reason} {kind.name} ({event.detail}) in {test}"] += 1
    return ran


member.Member._may_run = _counted  # type: ignore[method-assign]


def pytest_terminal_summary(terminalreporter: Any) -> None:
    terminalreporter.write_line(
        f"refusal tally: {TALLY['judged']} commands judged, {TALLY['ran']} ran"
    )
    for line, n in sorted(TALLY.items()):
        if line.startswith("refused"):
            terminalreporter.write_line(f"  {n} x {line}")
