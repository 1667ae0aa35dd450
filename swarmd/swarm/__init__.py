"""The swarm layer: roles, the readiness table and command tracker, the member's command
execution, the state file, and the data-plane adapter. See docs/architecture.md."""
