"""The state file of ``SwarmApp`` (``swarmd/swarmapp.py``): read at start (``boot``, or
``preview`` for ``swarmd check-config``) with the data plane built on it, and written while
the daemon runs on the writer's thread (``swarmd.filewriter``: the loop never waits for an
fsync), with the write-ahead: a ``VehicleRequest`` goes to the bridge once every write
asked for before it has ended (docs/dataplane.md, "Exactly once"). Split out of
``swarmapp.py`` by concern at 773 lines (style.md rule 19).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from functools import partial

from swarmd.dataplane import DataPlane, PairKeys
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, StartupError
from swarmd.filewriter import FileWriter
from swarmd.px4.vehicle import VehicleRequest
from swarmd.statefile import NodeState, StateDirError, boot
from swarmd.swarm.commander import KeptDecision
from swarmd.swarm.events import PersistExecuted
from swarmd.swarmapp_status import SwarmAppStatus


class StateSaves(SwarmAppStatus):
    """The state file read and the data plane built on it, the saves and the write-ahead;
    ``state``, ``plane`` and ``counters`` are shared (``SwarmAppStatus``)."""

    # the daemon's KeyRing and this boot's epoch (the one its SPDP announces) authenticate
    # the data plane's datagrams (docs/security.md)
    keys: PairKeys
    epoch: int
    # this node's boot epoch file held an earlier epoch, so a missing state file was
    # deleted, not never written (``state_file_missing``)
    booted_before: bool
    writer: FileWriter  # the daemon's writer thread (or one of this app's own)
    # the write-ahead across threads: state writes asked for and answered so far, and
    # the vehicle requests waiting, each with the writes that must end before it goes
    _saves_asked: int
    _saves_answered: int
    _held: deque[tuple[int, VehicleRequest]]
    _stopping: bool  # stop() began: a held request no longer goes to the vehicle

    def _state(self, read: Callable[[str, str], NodeState]) -> NodeState:
        """The state file by ``read`` (``boot``, or ``preview`` for a check), its refusal as
        ``start``'s one line (exit 73)."""
        try:
            return read(self.config.dataplane.state_dir, self.me.name)
        except StateDirError as exc:
            raise StartupError(f"dataplane.state_dir: {exc}", EX_CANTCREAT) from None

    def _make_plane(self, state: NodeState) -> DataPlane:
        """The data plane on ``state``; its refusal of the bundle as one line (exit 78)."""
        try:
            return DataPlane(
                self.bundle,
                self.me.name,
                keys=self.keys,
                epoch=self.epoch,
                incarnation=state.boot,
                executed_command_ids=state.executed,
                executed_outcomes=state.outcomes,
            )
        except ValueError as exc:
            raise StartupError(f"bundle rejected by the data plane: {exc}", EX_CONFIG) from None

    def _boot_dataplane(self) -> None:
        self.state = self._state(boot)
        if self.state.recovered_from:
            self.log.warning(
                "state_file_replaced", path=str(self.state.path), why=self.state.recovered_from
            )
        if self.state.missing and self.booted_before:
            # the record of the commands an earlier life ran is gone: exactly once now rests
            # on refusing them (docs/operations.md, "memory_lost"); a true first boot is silent
            self.counters["state_file_missing"] += 1
            self.log.warning(
                "state_file_missing",
                path=str(self.state.path),
                why="this node booted before (its boot epoch file held one) but its state "
                "file is gone: commands of an earlier life are refused memory_lost",
            )
        if self.state.decisions_dropped:  # times that cannot be right (statefile.load)
            self.log.warning(
                "state_decisions_dropped",
                path=str(self.state.path),
                dropped=self.state.decisions_dropped,
                ids_kept=self.state.decision_ids_kept,
                why=dropped_text(self.state),
            )
        if self.state.temps_removed:  # a crash mid-write (statefile.boot)
            self.log.warning(
                "state_temp_files_removed",
                path=str(self.state.path),
                count=self.state.temps_removed,
            )
        self.plane = self._make_plane(self.state)

    # ---- the saves and the write-ahead ------------------------------------------------------

    def _persist(self, event: PersistExecuted) -> None:
        """Write the state file, on the writer's thread (``swarmd.filewriter``): encoded
        now, so the write holds this event's state (or a newer one's, which holds it too).
        Each event is answered (``_saved``) once the write that holds it has ended."""
        if self.state is None:
            return
        self.state.executed = list(event.executed)
        self.state.outcomes = list(event.outcomes)
        offset = self._wall_offset()
        self.state.decisions = [on_clock(d, offset) for d in event.decisions]
        self.state.told_unsaved = list(event.told_unsaved)
        self.state.disarm_unconfirmed = list(event.disarm_unconfirmed)
        self._saves_asked += 1
        write = partial(self.state.write, self.state.encode())
        self.writer.submit("state", write, partial(self._saved, event.command))

    def _saved(self, command: tuple[str, int] | None, error: Exception | None) -> None:
        """On the loop: a write of the state file ended. A failed write is told (logged
        ``state_save_failed`` with the command it would have kept, counted, the decision
        marked unsaved for ``swarmctl outcomes``, its commander told ``[not saved on
        drone]``) and does not stop the command: docs/dataplane.md, "A failed save". Then
        the vehicle requests it held go (``_vehicle_request``)."""
        why: str | None = None
        if error is not None:
            why = str(error)
            self.counters["state_save_errors"] += 1
            commander, command_id = command or (None, None)
            self.log.error(
                "state_save_failed",
                error=why,
                commander=commander,
                command_id=command_id,
                effect="the command still runs; after a restart its answer is not re-reported "
                "and no copy of it runs again (docs/dataplane.md, 'A failed save')",
            )
        self._saves_answered += 1
        if self.driver is not None and self.core is not None:
            swarm = self.core
            self.driver.call(lambda now: swarm.state_saved(command, why, now))
        while not self._stopping and self._held and self._held[0][0] <= self._saves_answered:
            self._submit(self._held.popleft()[1])

    def _vehicle_request(self, request: VehicleRequest) -> None:
        """To the bridge once every state write asked for before it has ended: the
        write-ahead (``PersistExecuted`` before ``VehicleRequest``, docs/dataplane.md,
        "Exactly once") now that writes run on another thread; in order, behind any
        request still waiting. A wait past the command's validity is the vehicle core's to
        judge when the request reaches it (``not_after``: docs/dataplane.md, "Validity at
        the vehicle")."""
        if self._held or self._saves_answered < self._saves_asked:
            self._held.append((self._saves_asked, request))
            return
        self._submit(request)

    def _submit(self, request: VehicleRequest) -> None:
        if self.bridge is not None:
            self.bridge.submit(request)

    def _wall_offset(self) -> float:
        """Unix time minus the core's clock (``loop.time()``, CLOCK_MONOTONIC_RAW): the
        state file dates decisions on the wall clock, the only one two lives share."""
        return time.time() - self._driver().now()


def on_clock(kept: KeptDecision, offset: float) -> KeptDecision:
    """``kept`` with ``received_at`` moved by ``offset``: from the core's clock to Unix time
    (``offset`` = Unix time - loop time) or back (its negative)."""
    return kept._replace(received_at=kept.received_at + offset)


def dropped_text(state: NodeState) -> str:
    """The one line about the kept decisions ``statefile.load`` dropped for their time."""
    return (
        f"{state.decisions_dropped} earlier decision(s) dropped from swarmctl outcomes' view "
        f"({state.decisions_problem}); their ids stay executed, {state.decision_ids_kept} of "
        "them added there, so none of those commands runs again"
    )
