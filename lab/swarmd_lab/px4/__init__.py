"""The vehicle simulators (not PX4): ``sim_model`` the sans-IO vehicle both backends fly,
``virtual`` vehicle and companion joined on virtual time, ``vehicle_sim`` the MAVLink UDP
adapter (``swarmd-vehicle-sim``); and the PX4 stand-in over uXRCE-DDS: ``uxrce_client``
(PX4's client session on swarmd's XRCE client engine), ``xrce_standin`` (that + the vehicle),
``xrce_vehicle`` (its UDP adapter, ``swarmd-px4-xrce``). See docs/px4.md for what they copy
from PX4 and where they depart.
"""
