"""swarmd: onboard discovery daemon for PX4 drone swarms.

Implements network-aware, preloaded DDS discovery after Lee, Kim and Moon,
"Optimizing DDS Discovery for Swarm UAVs Through Preloading and Network Awareness",
Drones 2025, 9(8), 564.
"""

__version__ = "0.1.0"
