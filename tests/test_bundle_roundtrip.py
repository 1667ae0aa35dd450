"""Round trip and determinism over generated missions (hypothesis): mission -> bundle bytes ->
loaded model equals the built model, re-encodes to the same body, and the same mission
always gives byte-identical bundles. The match table agrees with ``Bundle.matches``."""

from __future__ import annotations

import hashlib
from typing import Any

import yaml
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.bundle.build import build_bundle, build_dev_bundle
from swarmd.bundle.encoding import HEADER_SIZE, SIGNATURE_SIZE, encode_body, split
from swarmd.bundle.keys import raw_public
from swarmd.bundle.loader import read_bundle
from swarmd.bundle.mission import Mission, parse_mission
from swarmd.bundle.model import EndpointKind, derive_guid_prefix, endpoint_entity_id
from swarmd.bundle.summary import node_matches
from swarmd.rtps.ports import max_participant_index, metatraffic_unicast_port

FIXED_SIGNING_KEY = Ed25519PrivateKey.from_private_bytes(bytes(range(32)))

QOS_CHOICES = st.fixed_dictionaries(
    {},
    optional={
        "reliability": st.sampled_from(["best_effort", "reliable"]),
        "durability": st.sampled_from(["volatile", "transient_local"]),
        "history_depth": st.integers(1, 100),
        "liveliness": st.sampled_from(["automatic", "manual_by_participant", "manual_by_topic"]),
        "liveliness_lease_s": st.one_of(
            st.none(), st.integers(1, 60_000).map(lambda ms: ms / 1000)
        ),
    },
)


@st.composite
def missions(draw: st.DrawFn) -> dict[str, Any]:
    domain_id = draw(st.integers(0, 232))
    n = draw(st.integers(1, 8))
    indices = draw(
        st.lists(
            st.integers(0, max_participant_index(domain_id)), min_size=n, max_size=n, unique=True
        )
    )
    sysids = draw(st.lists(st.integers(1, 254), min_size=n, max_size=n, unique=True))
    names = [f"n{i}-{draw(st.sampled_from(['a', 'b', 'uav']))}" for i in range(n)]
    roles = ["commander"] + [draw(st.sampled_from(["member", "commander"])) for _ in range(n - 1)]
    participants = []
    for i in range(n):
        p: dict[str, Any] = {
            "name": names[i],
            "index": indices[i],
            "role": roles[i],
            "mavlink_sysid": sysids[i],
        }
        if draw(st.booleans()):
            p["ipv4"] = f"10.1.{i}.{draw(st.integers(1, 254))}"
        participants.append(p)
    selector = st.one_of(
        st.just("all"),
        st.just("commander"),
        st.lists(st.sampled_from(names), min_size=1, max_size=3),
    )
    topic_names = draw(
        st.lists(
            st.from_regex(r"[a-z][a-z0-9_]{0,8}(/[a-z][a-z0-9_]{0,8}){0,2}", fullmatch=True),
            min_size=1,
            max_size=5,
            unique=True,
        )
    )
    topics = []
    for t in topic_names:
        topic: dict[str, Any] = {
            "name": t,
            "type": draw(st.sampled_from(["swarmd::Readiness", "a::b::C", "Plain"])),
            "writers": draw(selector),
            "readers": draw(selector),
        }
        topic.update(draw(QOS_CHOICES))
        topics.append(topic)
    doc: dict[str, Any] = {
        "swarm": draw(st.from_regex(r"[a-z0-9][a-z0-9_.-]{0,20}", fullmatch=True)),
        "domain_id": domain_id,
        "participants": draw(st.permutations(participants)),
        "topics": topics,
    }
    if draw(st.booleans()):
        t_min = draw(st.integers(1, 30_000))
        doc["discovery"] = {
            "t_min_s": t_min / 1000,
            "t_max_s": draw(st.integers(t_min, 60_000)) / 1000,
            "lease_s": draw(st.integers(1, 100)),
        }
    return doc


def _parse(doc: dict[str, Any]) -> Mission:
    return parse_mission(yaml.safe_dump(doc, sort_keys=False), "gen.yaml")


def _node_keys(m: Mission) -> dict[str, tuple[bytes, bytes]]:
    return {
        p.name: (
            raw_public(
                Ed25519PrivateKey.from_private_bytes(hashlib.sha256(p.name.encode()).digest())
            ),
            hashlib.sha256(b"x25519|" + p.name.encode()).digest(),
        )
        for p in m.participants
    }


@settings(max_examples=60, deadline=None)
@given(missions())
def test_round_trip_and_determinism(doc: dict[str, Any]) -> None:
    mission = _parse(doc)
    keys = _node_keys(mission)
    built = build_bundle(mission, FIXED_SIGNING_KEY, keys)
    again = build_bundle(_parse(doc), FIXED_SIGNING_KEY, dict(reversed(list(keys.items()))))
    assert built.data == again.data  # same mission -> byte-identical bundle

    loaded = read_bundle(built.data, trusted_key=raw_public(FIXED_SIGNING_KEY))
    assert loaded == built.bundle
    env = split(built.data)
    assert encode_body(loaded) == env.body
    assert len(built.data) == HEADER_SIZE + len(env.body) + SIGNATURE_SIZE
    assert loaded.content_sha256 == hashlib.sha256(env.body).digest()

    # identities are the derived ones, so the engine can recompute them from SPDP alone
    for p in loaded.participants:
        assert p.guid_prefix == derive_guid_prefix(mission.swarm, mission.domain_id, p.index)
        assert loaded.by_prefix(p.guid_prefix) == p
        assert loaded.metatraffic_port(p) == metatraffic_unicast_port(mission.domain_id, p.index)
        for e in p.endpoints:
            assert e.entity_id == endpoint_entity_id(loaded.topic(e.topic).index, e.kind)
    # every mission writer/reader became exactly one endpoint
    for t in mission.topics:
        for kind, names in ((EndpointKind.WRITER, t.writers), (EndpointKind.READER, t.readers)):
            holders = [
                p.name
                for p in loaded.participants
                for e in p.endpoints
                if (e.topic, e.kind) == (t.name, kind)
            ]
            assert sorted(holders) == sorted(names)


@settings(max_examples=40, deadline=None)
@given(missions())
def test_match_table_agrees_with_bundle_matches(doc: dict[str, Any]) -> None:
    bundle = build_dev_bundle(_parse(doc)).bundle
    table = node_matches(bundle)
    for local in bundle.participants:
        from_table = {
            (row["topic"], row["kind"], peer) for row in table[local.name] for peer in row["peers"]
        }
        from_model = {
            (m.topic, m.local_kind.value, peer.name)
            for peer in bundle.participants
            if peer.name != local.name
            for m in bundle.matches(local, peer)
        }
        assert from_table == from_model


def test_dev_bundles_are_reproducible_but_differ_from_signed_ones() -> None:
    doc = {
        "swarm": "s",
        "domain_id": 0,
        "participants": [{"name": "a", "index": 0, "role": "commander", "mavlink_sysid": 1}],
        "topics": [{"name": "t", "type": "T", "writers": "all", "readers": "all"}],
    }
    a, b = build_dev_bundle(_parse(doc)), build_dev_bundle(_parse(doc))
    assert a.data == b.data and a.dev
    signed = build_bundle(_parse(doc), FIXED_SIGNING_KEY, _node_keys(_parse(doc)))
    assert signed.data != a.data
