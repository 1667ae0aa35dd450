"""The ``dataplane:`` and ``ros2:`` sections: the services a daemon runs beside discovery
(docs/dataplane.md, docs/ros2.md), and the local users allowed to be its ROS 2 nodes.
"""

from __future__ import annotations

import yaml

from swarmd.config.model import DataplaneSection, Ros2Section
from swarmd.config.reader import FieldReader, Nodes


class ServiceFields(FieldReader):
    def dataplane(self, f: Nodes) -> DataplaneSection:
        d = DataplaneSection()
        period = d.readiness_period_s
        if "readiness_period_s" in f:
            # the data plane package is imported only when the field is set: the daemon
            # loads it once its engine runs (docs/benchmarks.md, "Daemon start-up")
            from swarmd.dataplane.validity import MIN_REPORT_PERIOD_MS

            period = self.number(
                f["readiness_period_s"],
                "dataplane.readiness_period_s",
                MIN_REPORT_PERIOD_MS / 1000.0,  # the report log's cap assumes it
                60.0,
                " s",
            )
        stale = (
            self.number(f["stale_after_s"], "dataplane.stale_after_s", 0.1, 600.0, " s")
            if "stale_after_s" in f
            else max(d.stale_after_s, 3 * period)
        )
        if stale <= period:
            where = f["stale_after_s"] if "stale_after_s" in f else f["readiness_period_s"]
            self.fail(
                where,
                "dataplane.stale_after_s",
                f"{stale:g} s does not exceed readiness_period_s {period:g} s: every member "
                "would look stale between two reports",
                "make stale_after_s at least 2-3 readiness periods",
            )
        return DataplaneSection(
            enabled=self.boolean(f["enabled"], "dataplane.enabled") if "enabled" in f else True,
            readiness_period_s=period,
            stale_after_s=stale,
            state_dir=(self.path(f["state_dir"], "dataplane.state_dir") or d.state_dir)
            if "state_dir" in f
            else d.state_dir,
        )

    def ros2(self, f: Nodes) -> Ros2Section:
        d = Ros2Section()
        port = (
            self.number(f["relay_port"], "ros2.relay_port", 1, 65535)
            if "relay_port" in f
            else d.relay_port
        )
        if port != int(port):
            self.fail(f["relay_port"], "ros2.relay_port", f"{port} is no port", "write e.g. 7399")
        return Ros2Section(
            relay=self.boolean(f["relay"], "ros2.relay") if "relay" in f else True,
            relay_port=int(port),
            lease_s=self.number(f["lease_s"], "ros2.lease_s", 2.0, 600.0, " s")
            if "lease_s" in f
            else d.lease_s,
            node_users=self.node_users(f["node_users"]) if "node_users" in f else None,
        )

    def node_users(self, node: yaml.Node) -> frozenset[int]:
        path = "ros2.node_users"
        if isinstance(node, yaml.ScalarNode):
            return frozenset({self.user(node, path)})
        if not isinstance(node, yaml.SequenceNode) or not node.value:
            self.fail(node, path, "expected a user or a list of users",
                      "write e.g. node_users: [ros]  (names or uids)")  # fmt: skip
        return frozenset(self.user(item, path) for item in node.value)
