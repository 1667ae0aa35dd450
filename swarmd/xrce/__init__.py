"""DDS-XRCE 1.0 (OMG formal/20-02-01) as PX4's ``uxrce_dds_client`` speaks it: a sans-IO
codec (``message``, ``binary``, ``framing``), session engines for the agent and the client
side (``session``), and PX4's topic layouts (``px4_types``). No asyncio, sockets or clocks
here (style.md rule 1): bytes and ``now`` in, bytes, events and timer deadlines out.
"""
