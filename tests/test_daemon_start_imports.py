"""A restarted daemon starts its discovery engine before it loads the swarm layer (issue 20,
the reboot at N = 20; docs/benchmarks.md, "Daemon start-up").

The engine's passive clock (paper section 4.1) runs from its construction, so every import
before it delays the drone's first announcement. ``swarmd run`` is run in a fresh
interpreter, as its console script runs it, with the flight's config (data plane, a MAVLink
PX4 link); at the engine's construction the process prints what it has loaded and exits.
The PX4 bridge and pymavlink, the XRCE backend, the data plane, the swarm layer, the ROS 2
relay, the control socket and check-config's own modules must not be among them (of the
data plane, only the module whose bound the config check reads, and its types): they load
after, inside the passive window. What they refuse still stops the start before READY=1
(``tests/test_daemon_process.py``, ``tests/test_check_config_startup.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.daemon_support import (
    BundleFiles,
    clean_env,
    loopback_config,
    run_domain,
    swarm_sections,
    write_bundle,
)

# loaded by the daemon once its engine runs, never before it
AFTER_THE_ENGINE = (
    "swarmd.swarmapp",
    "swarmd.swarmapp_status",
    "swarmd.swarmapp_px4",
    "swarmd.swarmapp_saves",
    "swarmd.swarmapp_events",
    "swarmd.swarmapp_requests",
    "swarmd.px4.bridge",
    "swarmd.px4.xrce_backend",
    "swarmd.xrce",
    "pymavlink",
    # the data plane itself; the config check reads one bound of its validity module
    # (dataplane.readiness_period_s), which loads that module and its types only
    "swarmd.dataplane.plane",
    "swarmd.swarm",
    "swarmd.ros2app",
    "swarmd.ros2",
    "swarmd.control",
    "swarmd.cli.sandbox_check",
    "swarmd.cli.unit_user",
)
# the console script's two lines, with the engine's construction reporting sys.modules
PROBE = """\
import json, os, sys
import swarmd.discovery.engine as engine
init = engine.DiscoveryEngine.__init__
def report(self, *args, **kwargs):
    init(self, *args, **kwargs)
    print(json.dumps(sorted(sys.modules)), flush=True)
    os._exit(0)
engine.DiscoveryEngine.__init__ = report
from swarmd.cli.swarmd_main import main
sys.exit(main())
"""


def _loaded_at_the_engine(config: Path) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, "run", "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
        env=clean_env(),
        check=False,
    )
    assert out.returncode == 0, out.stderr
    loaded: list[str] = json.loads(out.stdout.strip().splitlines()[-1])
    return set(loaded)


def test_the_engine_starts_before_the_swarm_layer_is_loaded(workdir: Path) -> None:
    files: BundleFiles = write_bundle(workdir, 3, domain_id=run_domain() + 7)
    sections = swarm_sections(workdir / "state", "udpin:127.0.0.1:14540")
    loaded = _loaded_at_the_engine(loopback_config(workdir, files, "uav2", extra=sections))
    assert "swarmd.discovery.engine" in loaded and "swarmd.daemon" in loaded
    early = sorted(
        m for m in loaded if any(m == a or m.startswith(a + ".") for a in AFTER_THE_ENGINE)
    )
    assert early == [], early
