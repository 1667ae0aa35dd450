"""Authentication from the bundle's keys, with no handshake (issue 10, docs/security.md).

Sans-IO like the codec and the engine: no sockets, no clock, no files beyond what the caller
hands in. Modules:

- ``keys``: ``NodeSecrets`` (this node's Ed25519 + X25519 private keys from node.key) and
  ``KeyRing`` (every bundle participant's public keys: sign, verify, pairwise keys).
- ``freshness``: ``Freshness`` (boot epoch, sequence), ``SendCounter``, ``ReplayWindow``.
- ``spdp``: the SPDP authenticator (a swarmd vendor PID, docs/wire.md) and the verifier the
  discovery engine runs before any state changes: cheap checks, budgets, then Ed25519.
- ``epoch``: the persisted boot epoch (the one module here that touches a file; the daemon
  calls it once at start-up, before the first send).
"""
