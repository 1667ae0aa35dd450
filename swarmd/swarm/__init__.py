"""The swarm layer, sans-IO: roles (``roles``), the commander's readiness table and command
tracker (``commander``), and ``SwarmCore`` (``core``: readiness reports, requests, a member's
execution decisions). Its I/O: the state file (``statefile``) and the user-data socket
(``userdata``); ``swarmd.swarmapp`` wires them. See docs/architecture.md."""
