"""sd_listen_fds(3) without libsystemd: the sockets systemd bound for us before we started.

With socket activation (``systemd/swarmd-px4.socket``) systemd binds the socket at boot,
as root, and keeps it open across every restart of the service; the service receives it as
an open file descriptor. The protocol (sd_listen_fds(3), "Notes"):

- ``LISTEN_PID`` is the pid the descriptors are meant for (a child that inherited the
  environment must not take them);
- ``LISTEN_FDS`` is how many, starting at descriptor 3 (``SD_LISTEN_FDS_START``);
- ``LISTEN_FDNAMES`` (optional) their names, colon-separated, from ``FileDescriptorName=``;
  a descriptor without one is called ``unknown``.

As sd_listen_fds(3) does with ``unset_environment``, the three variables are removed once
read, and every descriptor gets ``FD_CLOEXEC`` so no child process inherits the socket.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import MutableMapping
from typing import Final

SD_LISTEN_FDS_START: Final = 3
# systemd passes at most a few; a larger count is a broken environment, not a reason to
# walk thousands of descriptors
MAX_LISTEN_FDS: Final = 64
UNNAMED: Final = "unknown"  # sd_listen_fds_with_names(3)'s name for a descriptor without one


class ListenFdsError(ValueError):
    """The LISTEN_* variables are set for us but malformed; ``str()`` is one line."""


def listen_fds(
    environ: MutableMapping[str, str] | None = None, *, pid: int | None = None
) -> dict[str, list[int]]:
    """The descriptors systemd passed us, by name (``FileDescriptorName=``).

    Empty when nothing was passed or it was meant for another process. Raises
    ``ListenFdsError`` when the variables are for us but cannot be read.
    """
    env = os.environ if environ is None else environ
    target = env.get("LISTEN_PID", "")
    count_text = env.get("LISTEN_FDS", "")
    names_text = env.get("LISTEN_FDNAMES")
    for key in ("LISTEN_PID", "LISTEN_FDS", "LISTEN_FDNAMES"):
        env.pop(key, None)
    if not target or not count_text:
        return {}
    if not target.isdigit() or int(target) != (os.getpid() if pid is None else pid):
        return {}  # meant for another process (our parent, say)
    if not count_text.isdigit() or not 0 <= int(count_text) <= MAX_LISTEN_FDS:
        raise ListenFdsError(
            f"LISTEN_FDS={count_text!r} is not a count 0..{MAX_LISTEN_FDS}; fix: start swarmd "
            "from its unit (systemd sets LISTEN_FDS), or unset LISTEN_FDS and LISTEN_PID"
        )
    count = int(count_text)
    names = names_text.split(":") if names_text else [UNNAMED] * count
    if len(names) != count:
        raise ListenFdsError(
            f"LISTEN_FDNAMES names {len(names)} descriptors but LISTEN_FDS={count}; fix: "
            "start swarmd from its unit, or unset LISTEN_FDS, LISTEN_FDNAMES and LISTEN_PID"
        )
    out: dict[str, list[int]] = {}
    for offset, name in enumerate(names):
        fd = SD_LISTEN_FDS_START + offset
        try:
            flags = fcntl.fcntl(fd, fcntl.F_GETFD)
        except OSError:
            raise ListenFdsError(
                f"LISTEN_FDS={count} but descriptor {fd} is not open; fix: start swarmd from "
                "its unit, or unset LISTEN_FDS and LISTEN_PID"
            ) from None
        fcntl.fcntl(fd, fcntl.F_SETFD, flags | fcntl.FD_CLOEXEC)
        out.setdefault(name or UNNAMED, []).append(fd)
    return out
