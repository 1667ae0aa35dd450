"""PID 1's part for the production-layout tests, run as root inside fresh mount and network
namespaces (``unshare --mount --net``; ``tests/layout/install.py`` starts it).

At start it lays out a drone as ``docs/deploy.md`` says, in the namespace only (overlays on
/etc, /opt and /var/lib, a tmpfs on /run: the host is never written): the interpreter at
/opt/swarmd/python, a venv at /opt/swarmd/venv holding a copy of the ``swarmd`` package
and its console scripts, system user ``swarmd`` (in ``dialout``), a local user
``swarmd-attacker`` and an operator ``swarmd-operator`` in group ``swarmd``, /etc/swarmd
(0750 root:swarmd) with the config (0640), the flashed /var/lib/swarmd owned by swarmd.

Then it plays systemd for ``systemd/swarmd-px4.socket``, ``systemd/swarmd-xrce.socket`` and
``systemd/swarmd.service``, one JSON command per stdin line, one JSON reply per stdout line:

- ``{"cmd": "socket", "port": P, "name": N}`` binds 127.0.0.1:P as root with SO_REUSEADDR
  (as systemd does for every socket unit) for the unit whose ``FileDescriptorName=`` is N
  (``px4`` or ``xrce``) and keeps it across every daemon restart; ``port: null`` closes it
  (the socket unit stopped or not installed);
- ``{"cmd": "start"}``: RuntimeDirectory=, StateDirectory= (chown, mode), then the service's
  process: its own mount namespace with the unit's hardening that a namespace allows
  (ProtectSystem=strict, ProtectHome=, PrivateTmp=), the sockets from descriptor 3 on in
  the order of the service's ``Sockets=`` with LISTEN_FDS/LISTEN_FDNAMES/LISTEN_PID
  (sd_listen_fds(3)), NOTIFY_SOCKET, UMask=0027,
  an empty capability bounding set, NoNewPrivileges=, User=swarmd with its groups; the
  reply comes at READY=1 or at its exit;
- ``{"cmd": "stop"}``: SIGTERM, its exit code, the runtime directory removed;
- ``{"cmd": "quit"}``.

Standard library only: it runs before anything is installed.
"""

from __future__ import annotations

import contextlib
import json
import os
import pwd
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

START_WAIT_S = 30.0
STOP_WAIT_S = 10.0
NOTIFY_DIR = Path("/run/layout-systemd")
DEPS = "/opt/swarmd/deps"  # the test venv's site-packages, bound read-only
STAGED = "/opt/swarmd/.swarmd-package"


def sh(*argv: str) -> None:
    subprocess.run(argv, check=True, capture_output=True, timeout=60)


def overlay(target: str, work: Path) -> None:
    upper, scratch = work / "upper", work / "work"
    upper.mkdir(parents=True)
    scratch.mkdir()
    sh("mount", "-t", "overlay", "overlay", "-o",
       f"lowerdir={target},upperdir={upper},workdir={scratch}", target)  # fmt: skip


def lay_out(spec: dict[str, Any]) -> None:
    """The namespace's file system, then the install steps of docs/deploy.md."""
    scratch = Path(spec["scratch"])
    for target in ("/etc", "/opt", "/var/lib"):
        overlay(target, scratch / target.strip("/").replace("/", "-"))
    sh("mount", "-t", "tmpfs", "-o", "mode=0755", "tmpfs", "/run")
    prefix = spec["interpreter_prefix"]
    for source, target in ((prefix, "/opt/swarmd/python"), (spec["dependencies"], DEPS)):
        Path(target).mkdir(parents=True)
        sh("mount", "--bind", source, target)
        sh("mount", "-o", "remount,bind,ro", target)
    # the package, copied before the homes are hidden (a checkout may live in one)
    shutil.copytree(spec["package"], STAGED, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(spec["flashed"], "/var/lib/swarmd")  # what 'bundle flash' wrote
    for home in ("/root", "/home"):
        # ProtectHome=: nothing of a home is visible, except the test's own paths that live
        # in one (this machine's interpreter, whose RUNPATH names its path, the test venv and
        # the checkout; on a drone the interpreter is /opt/swarmd/python)
        inside = [path for path in spec["mirrors"] if path.startswith(home + "/")]
        staged = []
        for n, path in enumerate(inside):
            stage = f"/opt/swarmd/.mirror/{home.strip('/')}-{n}"
            Path(stage).mkdir(parents=True)
            sh("mount", "--bind", path, stage)
            staged.append((stage, path))
        if os.path.isdir(home):
            sh("mount", "-t", "tmpfs", "-o", "mode=0755", "tmpfs", home)
        for stage, path in staged:
            Path(path).mkdir(parents=True, exist_ok=True)
            sh("mount", "--bind", stage, path)
    sh("ip", "link", "set", "lo", "up")
    sh("ip", "addr", "add", f"{spec['node_ipv4']}/32", "dev", "lo")  # the mission's pin
    # 3. user, groups
    sh("useradd", "--system", "--home-dir", "/var/lib/swarmd", "--shell", "/usr/sbin/nologin",
       "swarmd")  # fmt: skip
    sh("usermod", "-aG", "dialout", "swarmd")
    sh("useradd", "--no-create-home", "--shell", "/bin/sh", "swarmd-attacker")
    sh("useradd", "--no-create-home", "--shell", "/bin/sh", "-G", "swarmd", "swarmd-operator")
    # 2. the venv and swarmd in it (a copy of the package, as pip would install it)
    python = "/opt/swarmd/python/bin/python3.11"
    sh(python, "-m", "venv", "--without-pip", "/opt/swarmd/venv")
    site = Path("/opt/swarmd/venv/lib/python3.11/site-packages")
    # the dependencies: the test venv's packages as a plain path (its .pth files, among
    # them the editable finder of the developer's swarmd, are not processed)
    (site / "swarmd-deps.pth").write_text(DEPS + "\n")
    shutil.move(STAGED, site / "swarmd")
    for name, module in (("swarmd", "swarmd_main"), ("swarmctl", "swarmctl")):
        script = Path("/opt/swarmd/venv/bin") / name
        script.write_text(
            "#!/opt/swarmd/venv/bin/python3.11\nimport sys\n"
            f"from swarmd.cli.{module} import main\nsys.exit(main())\n"
        )
        script.chmod(0o755)
    sh("ln", "-sfn", "/opt/swarmd/venv/bin/swarmctl", "/usr/local/bin/swarmctl")
    # 4. config, key and bundle
    sh("install", "-d", "-m", "0750", "-o", "root", "-g", "swarmd", "/etc/swarmd")
    config = Path("/etc/swarmd/swarmd.yaml")
    config.write_text(spec["config"])
    sh("chown", "root:swarmd", str(config))
    config.chmod(0o640)
    sh("chown", "-R", "swarmd:swarmd", "/var/lib/swarmd")
    # 5. the unit where docs/deploy.md installs it: check-config reads its sandbox
    units = Path("/etc/systemd/system")
    units.mkdir(parents=True, exist_ok=True)
    shutil.copy(Path(spec["package"]).parent / "systemd" / "swarmd.service", units)
    NOTIFY_DIR.mkdir(mode=0o755)


class Systemd:
    """The socket units' sockets and the service's process."""

    def __init__(self, spec: dict[str, Any]) -> None:
        self.spec = spec
        self.socks: dict[str, socket.socket] = {}  # by FileDescriptorName=
        self.proc: subprocess.Popen[bytes] | None = None
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        path = NOTIFY_DIR / "notify"
        self.notify.bind(str(path))
        path.chmod(0o777)  # like /run/systemd/notify: any service may write
        self.notify_path = str(path)

    def socket_unit(self, port: int | None, name: str = "px4") -> dict[str, Any]:
        old = self.socks.pop(name, None)
        if old is not None:
            old.close()
        if port is None:
            return {"ok": True}
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # systemd's socket_address_listen
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)  # ReceiveBuffer=1M
        try:
            s.bind(("127.0.0.1", port))
        except OSError as exc:
            s.close()
            return {"ok": False, "error": exc.strerror}
        self.socks[name] = s
        return {"ok": True}

    def start(self) -> dict[str, Any]:
        user = pwd.getpwnam("swarmd")
        run = Path("/run/swarmd")  # RuntimeDirectory=swarmd, RuntimeDirectoryMode=0750
        run.mkdir(mode=0o750, exist_ok=True)
        os.chown(run, user.pw_uid, user.pw_gid)
        run.chmod(0o750)
        sh("chown", "-R", "swarmd:swarmd", "/var/lib/swarmd")  # StateDirectory=swarmd
        Path("/var/lib/swarmd").chmod(0o700)  # StateDirectoryMode=0700
        # Sockets=swarmd-px4.socket swarmd-xrce.socket: passed in that order
        named = [(n, self.socks[n].fileno()) for n in ("px4", "xrce") if n in self.socks]
        fds = tuple(fd for _, fd in named)
        log = open(self.spec["log"], "ab")  # noqa: SIM115 - the child's stderr
        self.proc = subprocess.Popen(
            [sys.executable, "-I", str(Path(__file__).with_name("exec_service.py")),
             json.dumps({"fds": named, "notify": self.notify_path})],
            pass_fds=fds, stdin=subprocess.DEVNULL, stdout=log, stderr=log,
        )  # fmt: skip
        log.close()
        deadline = time.monotonic() + START_WAIT_S
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.notify], [], [], 0.1)
            if ready:
                message = self.notify.recv(4096).decode(errors="replace")
                if "READY=1" in message.split("\n"):
                    return {"ready": True, "pid": self.proc.pid}
            code = self.proc.poll()
            if code is not None:
                self._runtime_gone()
                return {"ready": False, "exit": code}
        return {"ready": False, "exit": None, "error": "no READY=1"}

    def stop(self) -> dict[str, Any]:
        if self.proc is None:
            return {"exit": None}
        proc, self.proc = self.proc, None
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait(STOP_WAIT_S)
        self._runtime_gone()
        return {"exit": code}

    def _runtime_gone(self) -> None:
        shutil.rmtree("/run/swarmd", ignore_errors=True)  # RuntimeDirectoryPreserve=no

    def close(self) -> None:
        self.stop()
        for name in list(self.socks):
            self.socket_unit(None, name)
        self.notify.close()


def main() -> None:
    spec = json.loads(sys.argv[1])
    lay_out(spec)
    systemd = Systemd(spec)
    print(json.dumps({"ok": True, "pid": os.getpid()}), flush=True)
    try:
        for line in sys.stdin:
            request = json.loads(line)
            cmd = request["cmd"]
            if cmd == "socket":
                reply = systemd.socket_unit(request["port"], request.get("name", "px4"))
            elif cmd == "start":
                reply = systemd.start()
            elif cmd == "stop":
                reply = systemd.stop()
            elif cmd == "quit":
                break
            else:
                reply = {"error": f"unknown {cmd}"}
            print(json.dumps(reply), flush=True)
    finally:
        systemd.close()


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        main()
