"""The PX4 side of swarmd: readiness from PX4's own MAVLink messages, the take-off sequence
and the flight-controller backends.

Pure (no asyncio, no clock): ``constants``, ``messages``, ``readiness``, ``takeoff`` (and
``mavlink_codec``, pymavlink's codec only). asyncio lives in ``transport``,
``mavlink_backend`` and ``bridge``. The MAVLink vehicle simulator the tests and the demo fly
is a lab tool, ``swarmd_lab.px4``. See docs/px4.md.
"""
