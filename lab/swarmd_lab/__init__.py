"""swarmd's lab tools: everything used to test, simulate and demonstrate swarmd that never
runs on a drone (design.md, "Lab tools, not installed on a drone").

``sim`` the swarm simulator, ``demo`` (``make demo``), ``netns`` the network-namespace
builder shared by the tests, the demo and ``bench/wifi``, ``px4`` the MAVLink vehicle
simulator, ``start_barrier`` the testbed's fair-start launcher, ``memnet`` the in-memory
network that joins any sans-IO core on virtual time, and ``testing`` synthetic bundles and
seeded swarms of discovery engines. This package imports
``swarmd``; ``swarmd`` never imports it (tests/test_boundaries.py).
"""
