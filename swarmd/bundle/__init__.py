"""The firmware bundle (paper section 4.2, EDP preloading): mission -> signed bundle -> drone.

Modules, in data-flow order:

- ``mission``: the operator's YAML, checked with line numbers (``load_mission``).
- ``keys``: the swarm signing key and per-node announcement keys (Ed25519).
- ``build``: mission + keys -> sealed bundle bytes (``build_bundle``).
- ``encoding``: the canonical byte layout (docs/bundle-format.md).
- ``loader``: the daemon side, bytes -> verified ``model.Bundle`` (``load_bundle``).
- ``floor``: the daemon's anti-rollback floor, the highest bundle serial it accepted.
- ``model``: what a verified bundle tells the discovery engine.
- ``summary``: the ``show`` / ``verify`` views; ``flash``: writing bundles to drones.

This package file imports nothing, so ``from swarmd.bundle.model import ...`` in the sans-IO
discovery engine does not pull in YAML, cryptography or subprocess.
"""
