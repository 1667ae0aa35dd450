"""The smallest daemon config the parser takes, for tests and benches that add a section.

``swarmd.config`` needs ``node``, ``bundle`` (path and trusted key: not read while parsing)
and ``network``; everything else has a default.
"""

from __future__ import annotations

from typing import Final

MINIMAL_CONFIG: Final = """\
node: uav1
bundle:
  path: bundle.swb
  trusted_key: keys/swarm-signing.pub
network:
  interface: eth0
"""
