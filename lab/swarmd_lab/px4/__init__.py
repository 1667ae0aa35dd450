"""The MAVLink vehicle simulator (not PX4): ``sim_model`` the sans-IO vehicle, ``virtual``
vehicle and companion joined on virtual time, ``vehicle_sim`` the UDP adapter and the
``swarmd-vehicle-sim`` command. See docs/px4.md for what it copies from PX4 and where it
departs.
"""
