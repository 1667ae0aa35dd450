"""swarmd installed as ``docs/deploy.md`` says, in namespaces of its own, for attack tests.

``ProductionLayout`` provisions a drone on the "ground laptop" side (``swarmctl bundle
keygen``/``build``/``flash`` of ``firmware_bundle/missions/swarm3.yaml``, node ``lead``, and
``swarmctl px4 key --out`` for the autopilot), then starts ``supervisor.py`` as root in a
new mount and network namespace. Everything the install writes (/etc/swarmd, users in
/etc/passwd, /opt/swarmd, /var/lib/swarmd, /run/swarmd) lives in overlays and tmpfs mounts
of that namespace, which vanish with it: nothing is written to the host's file system or
user database, on any exit path (``close`` ends the supervisor, killing it if it hangs).

Commands run inside with ``nsenter``, as root or as any of its users through ``setpriv``
(``swarmd-attacker``: a local user; ``swarmd-operator``: in group ``swarmd`` as the docs
allow).
"""

from __future__ import annotations

import json
import select
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path
from typing import IO, Any, Final

import yaml

from swarmd.cli.swarmctl import main as swarmctl

REPO: Final = Path(__file__).resolve().parents[2]
HERE: Final = Path(__file__).resolve().parent
MISSION: Final = REPO / "firmware_bundle" / "missions" / "swarm3.yaml"
NODE: Final = "lead"
# the address the mission pins for NODE: the drone's network.ipv4 must be it (the daemon
# refuses to start otherwise, docs/security.md "Pinned addresses"); put on the namespace's lo
NODE_IPV4: Final = str(
    next(
        p["ipv4"] for p in yaml.safe_load(MISSION.read_text())["participants"] if p["name"] == NODE
    )
)
SWARM: Final = str(yaml.safe_load(MISSION.read_text())["swarm"])
REPLY_S: Final = 60.0
PROBE_S: Final = 30.0


def unavailable_reason() -> str | None:
    """Why the layout cannot be built here (for a skip), or None."""
    import os

    if os.geteuid() != 0:
        return "the production layout needs root (users, mounts, namespaces)"
    for tool in ("unshare", "nsenter", "setpriv", "useradd", "usermod", "mount", "ip"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (util-linux, passwd, iproute2)"
    return None


def shipped_config(**px4: Any) -> str:
    """config/swarmd.yaml with only the per-drone values set (and px4 overrides)."""
    cfg = yaml.safe_load((REPO / "config" / "swarmd.yaml").read_text())
    cfg["node"] = NODE
    cfg["network"] = {"interface": "lo", "ipv4": NODE_IPV4}
    cfg["link"]["sources"] = ["static"]
    cfg["logging"]["format"] = "json"
    cfg["px4"].update(px4)
    return yaml.safe_dump(cfg, sort_keys=False)


class ProductionLayout:
    """One drone's install in its own namespaces; see the module docstring."""

    def __init__(self, root: Path, *, config: str | None = None) -> None:
        self.root = root
        self.log = root / "swarmd.log"
        keys, flashed = root / "keys", root / "flashed"
        swb = root / "swarm3.swb"
        self.px4_key = root / "px4-signing-key.bin"
        for argv in (
            ["bundle", "keygen", "--out", str(keys), "--mission", str(MISSION)],
            ["bundle", "build", str(MISSION), "-o", str(swb),
             "--sign-key", str(keys / "swarm-signing.key")],
            ["bundle", "flash", str(swb), "--node", NODE, "--target", str(flashed),
             "--keys", str(keys)],
            ["px4", "key", "--keys", str(keys), "--swarm", SWARM, "--node", NODE,
             "--out", str(self.px4_key)],
        ):  # fmt: skip
            assert swarmctl(argv) == 0, argv
        spec = {
            "scratch": str(root / "overlays"),
            "interpreter_prefix": sys.base_prefix,
            # what stays visible if it lives in a home the namespace hides
            "mirrors": [sys.base_prefix, sys.prefix, str(REPO)],
            "dependencies": sysconfig.get_paths()["purelib"],
            "package": str(REPO / "swarmd"),
            "config": config if config is not None else shipped_config(),
            "flashed": str(flashed),
            "node_ipv4": NODE_IPV4,
            "log": str(self.log),
        }
        self.proc = subprocess.Popen(  # noqa: S603 - fixed argv
            ["unshare", "--mount", "--net", "--propagation", "private",  # noqa: S607
             sys.executable, "-I", str(HERE / "supervisor.py"), json.dumps(spec)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        )  # fmt: skip
        try:
            first = self._reply()
        except BaseException:
            self.close()
            raise
        self.pid = int(first["pid"])

    # ---- the supervisor -----------------------------------------------------------------

    def _reply(self) -> dict[str, Any]:
        out = self.proc.stdout
        assert out is not None
        ready, _, _ = select.select([out], [], [], REPLY_S)
        line = out.readline() if ready else b""
        if not line:
            self.proc.kill()
            err = self.proc.stderr.read().decode() if self.proc.stderr else ""
            raise RuntimeError(f"layout supervisor gave no reply: {err[-2000:]}")
        reply: dict[str, Any] = json.loads(line)
        return reply

    def _ask(self, **request: Any) -> dict[str, Any]:
        stdin: IO[bytes] | None = self.proc.stdin
        assert stdin is not None
        stdin.write(json.dumps(request).encode() + b"\n")
        stdin.flush()
        return self._reply()

    def socket_unit(self, port: int | None, name: str = "px4") -> dict[str, Any]:
        """systemd binds (or releases) a PX4 link's socket: ``px4`` (swarmd-px4.socket) or
        ``xrce`` (swarmd-xrce.socket, the uXRCE-DDS agent's port)."""
        return self._ask(cmd="socket", port=port, name=name)

    def start(self) -> dict[str, Any]:
        """``systemctl start swarmd``: the reply at READY=1 or the daemon's exit."""
        return self._ask(cmd="start")

    def stop(self) -> dict[str, Any]:
        return self._ask(cmd="stop")

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self._ask(cmd="quit")
            except (OSError, RuntimeError, ValueError):
                pass
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=20)
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()

    # ---- inside the namespaces ----------------------------------------------------------

    def command(self, argv: list[str], user: str | None = None) -> list[str]:
        enter = ["nsenter", "-t", str(self.pid), "-m", "-n", "--"]
        if user is not None:
            enter += ["setpriv", f"--reuid={user}", f"--regid={user}", "--init-groups",
                      "--inh-caps=-all", "--bounding-set=-all"]  # fmt: skip
        return enter + argv

    def run(
        self, argv: list[str], user: str | None = None, timeout: float = PROBE_S
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(  # noqa: S603 - argv list
            self.command(argv, user), capture_output=True, text=True, timeout=timeout, check=False
        )

    def popen(self, argv: list[str], user: str | None = None) -> subprocess.Popen[bytes]:
        """A background process inside; its stderr appended to ``root/popen.log``."""
        with (self.root / "popen.log").open("ab") as err:
            return subprocess.Popen(  # noqa: S603 - argv list
                self.command(argv, user), stdout=subprocess.DEVNULL, stderr=err
            )

    def python(self, code: str, *args: str, user: str | None = None) -> Any:
        """Run ``code`` with this interpreter inside (as ``user``); its JSON stdout."""
        proc = self.run([sys.executable, "-I", "-c", code, *args], user=user)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    def swarmctl(self, *args: str, user: str | None = None) -> subprocess.CompletedProcess[str]:
        return self.run(["/usr/local/bin/swarmctl", *args], user=user)

    def log_lines(self) -> list[str]:
        return self.log.read_text(errors="replace").splitlines() if self.log.exists() else []
