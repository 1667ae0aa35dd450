"""A state file deleted between two lives is logged, and counted in status.

The state file (``dataplane.state_dir``, swarmd.statefile) is the drone's record of
the commands it ran. A missing one starts afresh, which is right on a first boot; on a
node that booted before (its boot epoch file held an earlier epoch) it means the record
was deleted, and the new life then refuses its earlier lives' commands ``memory_lost``
(docs/operations.md, "memory_lost"). The operator is told: ``state_file_missing``
(warning: path, why), ``dataplane.state_file_missing`` in ``swarmctl status --json``.
A true first boot logs nothing new. Real daemons in this process, on the host loopback.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from structlog.testing import capture_logs

from swarmd.bundle.loader import load_bundle
from swarmd.config import load_config
from swarmd.statefile import state_path
from tests.daemon_support import (
    BundleFiles,
    in_process_daemon,
    loopback_config,
    run_domain,
    swarm_sections,
    write_bundle,
)


def _life(workdir: Path, files: BundleFiles, state_dir: Path) -> tuple[list[Any], int]:
    """One life of uav1 (started, then stopped): its log and its status counter."""
    cfg = loopback_config(workdir, files, extra=swarm_sections(state_dir, None))
    daemon = in_process_daemon(
        load_config(cfg), load_bundle(files.path, files.trusted_key, allow_dev=True), "uav1"
    )

    async def main() -> int:
        try:
            await daemon.start()
            counter: int = daemon.status()["dataplane"].get("state_file_missing", 0)
            return counter
        finally:
            await daemon.stop("test")

    with capture_logs() as logs:
        counter = asyncio.run(main())
    return logs, counter


def _missing(logs: list[Any]) -> list[Any]:
    return [e for e in logs if e["event"] == "state_file_missing"]


def test_a_deleted_state_file_is_logged_and_a_first_boot_is_not(workdir: Path) -> None:
    # domain + 14: never the ports of the other daemon test files in the same run
    files = write_bundle(workdir, 2, domain_id=run_domain() + 14)
    state_dir = workdir / "state"
    logs, counter = _life(workdir, files, state_dir)  # the first boot: no file, silent
    assert _missing(logs) == [] and counter == 0
    logs, counter = _life(workdir, files, state_dir)  # the file is there: silent
    assert _missing(logs) == [] and counter == 0
    path = state_path(state_dir, "uav1")
    path.unlink()
    logs, counter = _life(workdir, files, state_dir)
    [event] = _missing(logs)
    assert event["log_level"] == "warning"
    assert event["path"] == str(path)
    assert "memory_lost" in event["why"]
    assert counter == 1
