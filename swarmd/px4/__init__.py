"""The PX4 side of swarmd: readiness from PX4's own MAVLink messages, the take-off sequence,
the flight-controller backends, and a MAVLink vehicle simulator for tests and demos.

Pure (no asyncio, no clock): ``constants``, ``messages``, ``readiness``, ``takeoff``,
``sim_model``, ``virtual`` (and ``mavlink_codec``, pymavlink's codec only). asyncio lives in
``transport``, ``mavlink_backend``, ``bridge`` and ``vehicle_sim``. See docs/px4.md.
"""
