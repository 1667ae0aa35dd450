"""ROS 2 on swarmd in flight (issue 20): the ``ros2-swarmd`` contender's flight observer,
its per-drone node names, its link files and its reboot, without a channel.

On the relay route the other drones' node names in a node's graph come from swarmd's graph
participant, named as the bundle declares them in ``/`` (swarmd.ros2.graph), so the flight
mission declares one node ``drone<i>`` per drone and the observer reads a drone from a
node's fully qualified name. A reboot kills and restarts the drone's node and its swarmd.
The real run is ``tests/test_flight_stock.py``'s smoke test (``SWARMD_FLIGHT_SMOKE=1``).
"""

from __future__ import annotations

import io
import signal
from contextlib import redirect_stdout
from pathlib import Path
from typing import Any, cast

import pytest
from swarmd_lab.netns import Namespace

from bench.wifi import flight_run, ros2_contenders
from bench.wifi.flight_events import PeerEvents
from bench.wifi.peers.common import FlightEvents
from bench.wifi.peers.ros2_peer import GraphWatch, graph_drones
from bench.wifi.ros2_contenders import Ros2Contender, ros2_mission_text, swarmd_config
from swarmd.bundle.mission import parse_mission
from swarmd.config import load_config


class FakeProc:
    """A started process as the contender sees it: signals and waits are recorded."""

    def __init__(self, argv: list[str]) -> None:
        self.argv = argv
        self.signals: list[int] = []
        self.returncode: int | None = None

    def send_signal(self, sig: int) -> None:
        self.signals.append(sig)
        self.returncode = -sig

    def wait(self, timeout: float | None = None) -> int:
        return self.returncode if self.returncode is not None else 0

    def poll(self) -> int | None:
        return self.returncode


class FakeDrone:
    """A drone namespace never entered: ``popen`` records what would run there."""

    def __init__(self, i: int) -> None:
        self.name = f"nowhere-{i}"
        self.address = f"10.79.0.{i + 1}"
        self.started: list[FakeProc] = []

    def popen(self, argv: Any, **kwargs: Any) -> Any:
        proc = FakeProc(list(argv))
        self.started.append(proc)
        return proc


def fake(proc: object) -> FakeProc:
    assert isinstance(proc, FakeProc)
    return proc


def contender(name: str, tmp_path: Path, n: int = 3) -> tuple[Ros2Contender, list[FakeDrone]]:
    drones = [FakeDrone(i) for i in range(n)]
    c = Ros2Contender(
        name,
        cast(list[Namespace], drones),
        tmp_path,
        window_s=30,
        messages=2,
        link_dir=tmp_path / "flight",
    )
    c.flight_events = True
    return c, drones


@pytest.mark.parametrize(
    ("names", "want"),
    [
        ([("talker", "/drone3"), ("listener", "/drone0")], {0, 3}),  # stock flight peers
        ([("drone3", "/"), ("drone12", "/")], {3, 12}),  # the relay route's names
        ([("talker", "/"), ("listener", "/")], set()),  # the boot benchmark's names
        ([("drone", "/"), ("drone3x", "/"), ("dronex", "/drone")], set()),
        ([("drone2", "/other"), ("x", "/other/drone2"), ("drone\u0663", "/")], set()),
        ([("", "/"), ("talker", "")], set()),
    ],
)
def test_a_drone_is_read_from_the_nodes_fully_qualified_name(
    names: list[tuple[str, str]], want: set[int]
) -> None:
    assert graph_drones(names) == want


def test_the_relay_routes_graph_gives_lost_and_regained_per_drone() -> None:
    out = io.StringIO()
    with redirect_stdout(out):
        events = FlightEvents(True, 0)
        events.hello()
        watch = GraphWatch(events, 0)
        every = [("drone0", "/"), ("drone1", "/"), ("drone2", "/")]
        for names in (every, [("drone0", "/"), ("drone1", "/")], every):
            watch.update(names)
    measure = PeerEvents(3)
    measure.feed(0, out.getvalue().splitlines())
    assert [(p, c) for _, p, c in measure.changes[0]] == [
        (1, "discovered"),
        (2, "discovered"),
        (2, "lost"),
        (2, "regained"),
    ]


def test_the_flight_mission_declares_one_node_per_drone_with_the_same_endpoints() -> None:
    addresses = [f"10.79.0.{i + 1}" for i in range(4)]
    graph = parse_mission(ros2_mission_text(addresses, per_drone=True), "m.yaml").ros2
    boot = parse_mission(ros2_mission_text(addresses), "m.yaml").ros2
    assert graph is not None and boot is not None
    assert [(n.name, n.drones) for n in graph.nodes] == [
        (f"drone{i}", (f"uav{i + 1}",)) for i in range(4)
    ]
    assert graph.nodes[0].subscribes == boot.nodes[1].subscribes  # the listener's
    assert all(n.publishes == boot.nodes[0].publishes for n in graph.nodes[1:])
    assert [n.name for n in boot.nodes] == ["talker", "listener"]


def test_only_the_relay_route_in_flight_names_its_nodes_per_drone(tmp_path: Path) -> None:
    c, _ = contender("ros2-swarmd", tmp_path / "a")
    assert c.per_drone_nodes and c.node_name(2) == "drone2"
    assert c._argv(2, None, 10.0)[-2:] == ["--node", "drone2"]
    boot, _ = contender("ros2-swarmd", tmp_path / "c")
    boot.flight_events = False  # the boot benchmark: its talker/listener as before
    assert not boot.per_drone_nodes and boot.node_name(2) == "talker"
    assert "--node" not in boot._argv(2, None, 10.0)
    stock, _ = contender("ros2", tmp_path / "b")
    assert not stock.per_drone_nodes and "--node" not in stock._argv(0, None, 10.0)


def test_the_flight_profiles_are_each_drones_own_node(tmp_path: Path) -> None:
    c, _ = contender("ros2-swarmd", tmp_path)
    bundle, _key = ros2_contenders._write_ros2_bundle(c)
    envs = ros2_contenders._profiles(c, bundle, "--via-swarmd")
    for i, env in enumerate(envs):
        xml = Path(env["FASTDDS_DEFAULT_PROFILES_FILE"])
        assert xml == tmp_path / "ros2-profiles" / f"uav{i + 1}" / f"drone{i}.xml"
        assert "<address>::1</address>" in xml.read_text()  # the relay, on the drone


def test_the_daemons_read_the_flight_channels_link_files(tmp_path: Path) -> None:
    c, _ = contender("ros2-swarmd", tmp_path)
    bundle, key = ros2_contenders._write_ros2_bundle(c)
    for i in range(3):
        config = load_config(str(swarmd_config(c, i, bundle, key)))
        assert config.link.file == str(tmp_path / "flight" / f"link-{i}.json")
        assert config.link.sources[0] == "file"
        assert config.engine_mode == "adaptive" and config.ros2.relay
        assert config.dataplane.state_dir == str(tmp_path / f"state-uav{i + 1}")


def test_a_reboot_kills_and_restarts_the_node_and_its_swarmd(tmp_path: Path) -> None:
    c, drones = contender("ros2-swarmd", tmp_path)
    bundle, key = ros2_contenders._write_ros2_bundle(c)
    for i in range(3):
        swarmd_config(c, i, bundle, key)
        c.start_daemon(i)
    c._envs = [{"A": str(i)} for i in range(3)]
    c.procs = [drones[i].popen(["node", str(i)]) for i in range(3)]
    (tmp_path / "swarmd-uav2.log").write_bytes(b"first life\n")
    state = tmp_path / "state-uav2"
    state.mkdir()
    (state / "epoch").write_text("7")
    daemon, node = fake(c.daemons[1]), fake(c.procs[1])

    c.kill(1)
    assert node.signals == [signal.SIGKILL] and daemon.signals == [signal.SIGKILL]
    assert fake(c.daemons[0]).signals == [] and fake(c.procs[0]).signals == []  # nobody else

    c.restart(1, 20.0, "kept")
    assert state.exists()
    new_daemon, new_node = drones[1].started[-2:]
    assert fake(c.daemons[1]) is new_daemon and fake(c.procs[1]) is new_node
    assert "swarmd.cli.swarmd_main" in new_daemon.argv  # swarmd first, then the node
    assert new_daemon.argv[-1] == str(tmp_path / "swarmd-uav2.yaml")
    assert "--node" in new_node.argv and "drone1" in new_node.argv
    assert "--barrier" not in new_node.argv  # a reboot: no start barrier
    assert (tmp_path / "swarmd-uav2.log").read_bytes().startswith(b"first life")

    c.kill(1)
    c.restart(1, 20.0, "lost")
    assert not state.exists()  # the state dir lost with the reboot
    assert "swarmd.cli.swarmd_main" in drones[1].started[-2].argv
    c.close()


def test_a_stock_ros2_reboot_restarts_the_node_only(tmp_path: Path) -> None:
    c, drones = contender("ros2", tmp_path)
    c._envs = [{} for _ in range(3)]
    c.procs = [drones[i].popen(["node", str(i)]) for i in range(3)]
    c.kill(2)
    c.restart(2, 20.0, "lost")
    assert c.daemons == {} and len(drones[2].started) == 2
    assert "swarmd.cli.swarmd_main" not in drones[2].started[-1].argv
    c.close()


def test_ros2_on_swarmd_is_a_flight_contender_with_swarmds_loss_timer() -> None:
    assert "ros2-swarmd" in flight_run.FLIGHT_CONTENDERS
    assert "ros2-swarmd" in flight_run.PEER_OBSERVED  # the node's graph is the observer
    # the relay renews on loopback while swarmd has the drone: swarmd's lease decides
    assert flight_run.LOSS_TIMER_S["ros2-swarmd"] == flight_run.LEASE_S
    for refused in ("ros2-ds", "ros2-static"):
        assert refused not in flight_run.FLIGHT_CONTENDERS


def test_swarmd_under_the_nodes_is_polled_for_its_own_peer_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the run file then has swarmd's own re-discoveries beside the graph's
    # (bench/flight_slow_pair.py --parts: what swarmd took, what the relay added)
    c, _ = contender("ros2-swarmd", tmp_path)
    asked: list[tuple[str, str]] = []

    def request(sock: str, cmd: str) -> object:
        asked.append((sock, cmd))
        change = {"seq": 1, "peer": "uav1", "change": "regained", "ago_s": 0.5}
        return {"daemon": {"pid": 42}, "peer_changes": {"changes": [change], "last_seq": 1}}

    monkeypatch.setattr(flight_run, "request", request)
    under = flight_run.swarmd_under(c, 3)
    under.poll(100.0)
    under.poll(100.25)
    assert asked == [
        (str(ros2_contenders.swarmd_socket(c, i)), "status") for i in (0, 1, 2, 0)
    ]  # the daemons' own sockets, round robin; never the readiness table (the node's)
    assert under.changes[1] == [(99.5, 0, "regained")] and under.readiness == []
    assert under.changes[0] == [(99.5, 0, "regained")]  # one change, taken once per life
