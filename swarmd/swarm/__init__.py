"""The swarm layer, sans-IO: roles (``roles``), the commander's readiness table and command
tracker (``commander``), and ``SwarmCore`` (``core``: readiness reports, the driving
protocol) around the commander's side (``issuer``: requests, issuing, withdrawal) and the
member's (``member``: execution decisions, answers, re-reports). Its I/O is the daemon
tier's: the state file (``swarmd.statefile``) and the user-data socket (``swarmd.userdata``);
``swarmd.swarmapp`` wires them.
See docs/architecture.md."""
