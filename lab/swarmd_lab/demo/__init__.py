"""``make demo`` (``python -m swarmd_lab.demo --n N``): a whole swarm on one machine.

Each drone is a network namespace (``swarmd_lab.netns.Lan``) running a real ``swarmd run`` and a
``swarmd-vehicle-sim`` (a PX4-like MAVLink vehicle SIMULATOR, not PX4), with its Wi-Fi link
quality read from a file. The demo shows discovery, readiness, the commander's take-off and
every drone reaching IN_AIR, then writes ``demo-out/summary.json`` and a timeline PNG.
Without root it runs every drone on the loopback interface with distinct ports instead.

Modules: ``scenario`` (keys, mission, bundle, configs), ``hosts`` (namespaces or loopback),
``observe`` (status polling and the daemons' logs), ``view`` (the live terminal view),
``report`` (summary table, JSON, PNG), ``run`` (the sequence and the clean-up).
"""
