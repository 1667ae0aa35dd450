"""Authentication from the bundle's keys, with no handshake (issue 10, docs/security.md).

Sans-IO like the codec and the engine: no sockets, no clock, no files beyond what the caller
hands in. Modules:

- ``keys``: ``NodeSecrets`` (this node's Ed25519 + X25519 private keys from node.key) and
  ``KeyRing`` (every bundle participant's public keys: sign, verify, pairwise keys).
- ``freshness``: ``Freshness`` (boot epoch, sequence), ``SendCounter``, ``ReplayWindow``.
- ``spdp``: the SPDP authenticator (a swarmd vendor PID, docs/wire.md) and the verifier the
  discovery engine runs before any state changes: cheap checks, my receiver tag, budgets,
  then Ed25519.
- ``tags``: the receiver tags (issue 18): a 2-octet MAC per receiver under the pair's key,
  so only the claimed sender's datagrams ever spend its verification budget.
- ``epoch``: the persisted boot epoch, and ``windows``: the persisted SPDP replay windows
  (the two modules here that touch a file; the daemon calls them, at start-up and, for the
  windows, every few seconds and at stop).
"""
