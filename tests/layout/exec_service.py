"""What systemd does between fork and exec for ``systemd/swarmd.service`` (the parts a
namespace allows), then exec of ``ExecStart=``. Runs as root; the pid stays the daemon's.

Argument: JSON ``{"fds": [[NAME, N], ...], "notify": PATH}`` (the socket units' sockets, in
the service's ``Sockets=`` order, by ``FileDescriptorName=``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import fcntl
import grp
import json
import os
import pwd
import subprocess
import sys

CLONE_NEWNS = 0x00020000
MS_REC, MS_PRIVATE = 0x4000, 1 << 18
PR_SET_PDEATHSIG, PR_CAPBSET_DROP, PR_SET_NO_NEW_PRIVS = 1, 24, 38
SIGKILL = 9
EXEC_START = ["/opt/swarmd/venv/bin/swarmd", "run", "--config", "/etc/swarmd/swarmd.yaml"]
WRITABLE = ("/var/lib/swarmd", "/run/swarmd")  # StateDirectory=, RuntimeDirectory=
KERNEL_TREES = ("/proc", "/sys", "/dev")  # ProtectSystem=strict leaves these to other settings

libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)


def check(result: int, what: str) -> None:
    if result != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def mount(*argv: str) -> None:
    subprocess.run(["mount", *argv], check=True, capture_output=True, timeout=30)


def mount_points() -> list[str]:
    with open("/proc/self/mountinfo") as f:
        points = [line.split()[4].replace("\\040", " ") for line in f]
    return sorted(set(points))


def harden() -> None:
    # a mount namespace of the service's own, as systemd makes for these settings
    check(libc.unshare(CLONE_NEWNS), "unshare")
    check(libc.mount(None, b"/", None, MS_REC | MS_PRIVATE, None), "mount private")
    for tmp in ("/tmp", "/var/tmp"):  # PrivateTmp=yes
        mount("-t", "tmpfs", "-o", "mode=1777,nosuid,nodev", "tmpfs", tmp)
    for home in ("/home", "/run/user"):  # ProtectHome=yes (/root: see supervisor.py)
        if os.path.isdir(home):
            mount("-t", "tmpfs", "-o", "ro,mode=0755", "tmpfs", home)
    for path in WRITABLE:
        mount("--bind", path, path)
    # ProtectSystem=strict: everything read-only but the service's own directories
    for point in mount_points():
        if point in WRITABLE or any(point == t or point.startswith(t + "/") for t in KERNEL_TREES):
            continue
        if not os.path.exists(point):
            continue  # shadowed by a mount above it (the host's /run/* under our /run)
        mount("-o", "remount,bind,ro", point)


def main() -> None:
    spec = json.loads(sys.argv[1])
    user = pwd.getpwnam("swarmd")
    harden()
    env = {
        "PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
        "PYTHONUNBUFFERED": "1",  # Environment=
        "NOTIFY_SOCKET": spec["notify"],
        "HOME": user.pw_dir,
        "USER": "swarmd",
        "LOGNAME": "swarmd",
        "STATE_DIRECTORY": "/var/lib/swarmd",
        "RUNTIME_DIRECTORY": "/run/swarmd",
        "CONFIGURATION_DIRECTORY": "/etc/swarmd",
    }
    if spec["fds"]:  # sd_listen_fds(3): descriptor 3 on, named by LISTEN_FDNAMES
        # first out of the way (a passed descriptor may already sit at 3 or 4), then in order
        high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 100) for _, fd in spec["fds"]]
        for _, fd in spec["fds"]:
            os.close(fd)
        for n, fd in enumerate(high):
            os.dup2(fd, 3 + n)
            os.close(fd)
            os.set_inheritable(3 + n, True)
        env |= {
            "LISTEN_FDS": str(len(high)),
            "LISTEN_FDNAMES": ":".join(name for name, _ in spec["fds"]),
            "LISTEN_PID": str(os.getpid()),
        }
    os.umask(0o027)  # UMask=0027
    os.chdir("/")
    for cap in range(64):  # CapabilityBoundingSet= (empty)
        if libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            break
    groups = [user.pw_gid, grp.getgrnam("dialout").gr_gid]  # Group=, SupplementaryGroups=
    os.setgroups(groups)
    os.setgid(user.pw_gid)
    os.setuid(user.pw_uid)  # User=swarmd: every capability is gone with it
    # not systemd's: a killed test run must not leave the daemon holding the namespace (set
    # after setuid, which clears it)
    check(libc.prctl(PR_SET_PDEATHSIG, SIGKILL, 0, 0, 0), "pdeathsig")
    check(libc.prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0), "no_new_privs")  # NoNewPrivileges=
    os.execve(EXEC_START[0], EXEC_START, env)  # noqa: S606 - ExecStart=, a fixed argv


if __name__ == "__main__":
    main()
