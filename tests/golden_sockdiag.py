"""Record the sock_diag replies tests/test_sockdiag.py parses: ``python -m tests.golden_sockdiag``
(as root, port 7400 free). Prints the inodes and the Python constants to paste.

Three sockets on port 7400: ``::1``, ``127.0.0.1`` and ``::ffff:127.0.0.1`` (the last two
with SO_REUSEADDR); then swarmd.sockdiag's request for port 7400 with sequence numbers 101
(AF_INET6), 102 (AF_INET), 103 (family 99: EINVAL), 104 (AF_VSOCK: ENOENT), each reply
printed as one recv() returned it.
"""

from __future__ import annotations

import os
import socket
import textwrap

from swarmd.sockdiag import NETLINK_SOCK_DIAG, NLMSG_DONE, NLMSG_ERROR, RECV_BYTES, encode_request

PORT = 7400
NAMES = {
    (socket.AF_INET6, 0): "V6_ROWS", (socket.AF_INET6, 1): "V6_DONE",
    (socket.AF_INET, 0): "V4_ROWS", (socket.AF_INET, 1): "V4_DONE",
    (99, 0): "EINVAL_REPLY", (socket.AF_VSOCK, 0): "ENOENT_REPLY",
}  # fmt: skip


def main() -> None:
    bound = []
    for host, reuse in (("::1", False), ("127.0.0.1", True), ("::ffff:127.0.0.1", True)):
        s = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        if reuse:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((host, PORT))
        bound.append(s)
    print("# inodes", [os.fstat(s.fileno()).st_ino for s in bound])
    with socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, NETLINK_SOCK_DIAG) as ns:
        for seq, family in enumerate((socket.AF_INET6, socket.AF_INET, 99, socket.AF_VSOCK), 101):
            ns.send(encode_request(family, PORT, seq))
            for chunk in range(4):  # rows, then NLMSG_DONE (or one NLMSG_ERROR)
                data = ns.recv(RECV_BYTES)
                lines = "".join(f'    "{line}"\n' for line in textwrap.wrap(data.hex(), 88))
                print(f"{NAMES[(family, chunk)]} = bytes.fromhex(\n{lines})")
                if data[4] in (NLMSG_DONE, NLMSG_ERROR):
                    break
    for s in bound:
        s.close()


if __name__ == "__main__":
    main()
