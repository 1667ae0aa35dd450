"""Receiver tags and persisted replay windows (issue 18, ``swarmd.auth.tags``,
``swarmd.auth.windows``): a forgery by anyone but the sender never spends what a real peer
needs, whatever prefix and source address it carries; a restarted receiver keeps refusing
what it had already passed. Verifier-level tests first, then engines on a ``MemNet``."""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.testing import (
    Swarm,
    auth_for,
    build_swarm,
    engine_for,
    make_bundle,
    node_ipv4,
    peer_datagram,
)

from swarmd.auth.budget import SENDER_BURST
from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import (
    PLACEHOLDER,
    Refusal,
    SpdpAuth,
    authenticator_overhead,
    seal,
    tail_window,
)
from swarmd.auth.tags import MAX_RECEIVER_TAGS, ReceiverTags, tag_block_bytes
from swarmd.auth.windows import (
    decode_windows,
    encode_windows,
    load_windows,
    save_windows,
    windows_path,
)
from swarmd.bundle.model import Bundle
from swarmd.discovery import PeerDiscovered
from swarmd.rtps.spdp import encode_spdp_dispose

BUNDLE = make_bundle(4)
P = [p.guid_prefix for p in BUNDLE.participants]


def addr(i: int, bundle: Bundle = BUNDLE) -> tuple[str, int]:
    """Bundle participant ``i``'s exact metatraffic address (what a spoofer puts on)."""
    return node_ipv4(i), bundle.metatraffic_port(bundle.participants[i])


class _RandomTags:
    """An outsider's best: the genuine window, random tags (a ``Tagger``)."""

    def __init__(self, rng: random.Random, window: tuple[int, int]) -> None:
        self._rng = rng
        self._window = window

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        return self._window

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        return self._rng.randbytes(tag_block_bytes(count))


class _KeepTemplate(SpdpAuth):
    """Hands the unsealed template back (the forger builds on swarmd's own encoder)."""

    def seal(self, template: bytes) -> bytes:
        return template


def template_of(index: int, bundle: Bundle = BUNDLE) -> bytes:
    """What participant ``index`` would sign: its DATA(p) with the placeholder."""
    return peer_datagram(bundle, index, auth=_KeepTemplate(auth_for(bundle, index).keyring, 1, 0.0))


def outsider_forgery(
    index: int, seq: int, rng: random.Random, bundle: Bundle = BUNDLE, epoch: int = 2_000_000_000
) -> bytes:
    """A DATA(p) under participant ``index``'s prefix, fresh (a high epoch), signed with a
    key of the attacker's own and carrying random tags in the genuine window."""
    window = (0, bundle.size - 1)
    signer = Ed25519PrivateKey.generate()
    return seal(template_of(index, bundle), Freshness(epoch, seq), signer, _RandomTags(rng, window))


# ---- the verifier ----------------------------------------------------------------------


def test_each_receiver_holds_its_own_tag_and_the_datagram_names_whom_it_tags() -> None:
    sender = auth_for(BUNDLE, 0, epoch=7)
    multicast = peer_datagram(BUNDLE, 0, auth=sender)
    directed = peer_datagram(BUNDLE, 0, auth=sender, destination=P[2])
    plain = peer_datagram(BUNDLE, 0)
    assert tail_window(multicast) == (0, 3)  # every peer of a 4-node swarm
    assert tail_window(directed) == (1, 1)  # uav2 alone (position 1 after uav0)
    assert len(multicast) - len(plain) == authenticator_overhead(3) == 80 + 8  # 3 x 2 + pad
    for i in (1, 2, 3):
        verdict = auth_for(BUNDLE, i).check(P[0].value, multicast, addr(0), 0.0)
        assert verdict == Freshness(7, 1), i
    # the directed one: uav2 takes it, uav1 and uav3 refuse it before any signature
    assert auth_for(BUNDLE, 2).check(P[0].value, directed, addr(0), 0.0) == Freshness(7, 2)
    for i in (1, 3):
        receiver = auth_for(BUNDLE, i)
        assert receiver.check(P[0].value, directed, addr(0), 0.0) == Refusal.BAD_TAG
        assert receiver.counters()["verified"] == 0


def test_an_outsider_spoofing_the_commanders_prefix_and_address_spends_nothing() -> None:
    """Issue 18: forged SPDP under the commander's prefix, from its exact IP and port.
    Before the tags, 40 of them emptied the commander's budget at the member."""
    rng = random.Random(18)
    member = auth_for(BUNDLE, 1)
    genuine = auth_for(BUNDLE, 0, epoch=5)
    first = peer_datagram(BUNDLE, 0, auth=genuine)
    # three shapes: random tags; a genuine datagram's tags on another body; no tags at all
    altered = bytearray(first)
    altered[40] ^= 0x01  # a byte of the body: tags and signature copied as they were
    untagged = seal(template_of(0), Freshness(9, 1), Ed25519PrivateKey.generate())
    forgeries = [outsider_forgery(0, s, rng) for s in range(1, 2001)]
    forgeries += [bytes(altered), untagged]
    for forged in forgeries:
        assert member.check(P[0].value, forged, addr(0), 0.0) == Refusal.BAD_TAG
    assert member.counters()["verified"] == 0
    assert member.verifier.counters["auth_bad_tag"] == len(forgeries)
    assert member.verifier.counters["auth_budget_sender"] == 0
    # the same instant: the commander's whole burst is still there for its own datagrams
    assert member.check(P[0].value, first, addr(0), 0.0) == Freshness(5, 1)
    for _ in range(int(SENDER_BURST) - 1):
        d = peer_datagram(BUNDLE, 0, auth=genuine)
        assert isinstance(member.check(P[0].value, d, addr(0), 0.0), Freshness)


def test_a_captured_member_can_spend_only_its_own_budget() -> None:
    member = auth_for(BUNDLE, 1)
    captured = auth_for(BUNDLE, 2, epoch=77)  # uav2's node.key in the attacker's hands
    commander = auth_for(BUNDLE, 0, epoch=5)
    # as the commander: its tags are keyed with its own pair keys, so uav1's does not hold
    for _ in range(200):
        as_commander = peer_datagram(BUNDLE, 0, auth=captured)
        assert member.check(P[0].value, as_commander, addr(0), 0.0) == Refusal.BAD_TAG
    # as itself it passes the tag, and floods its own budget dry
    verdicts = [
        member.check(P[2].value, peer_datagram(BUNDLE, 2, auth=captured), addr(2), 0.0)
        for _ in range(200)
    ]
    assert verdicts.count(Refusal.BUDGET_SENDER) == 200 - SENDER_BURST
    # the commander's budget is untouched
    for _ in range(int(SENDER_BURST)):
        d = peer_datagram(BUNDLE, 0, auth=commander)
        assert isinstance(member.check(P[0].value, d, addr(0), 0.0), Freshness)


def test_a_large_swarm_rotates_the_window_so_every_peer_is_tagged() -> None:
    big = make_bundle(MAX_RECEIVER_TAGS + 8)  # 39 peers, 32 tags a datagram
    sender = auth_for(big, 0)
    sent = [peer_datagram(big, 0, auth=sender) for _ in range(3)]
    windows = [tail_window(d) for d in sent]
    assert windows == [(0, 32), (32, 32), (25, 32)]
    tagged: set[int] = set()
    sender_prefix = big.participants[0].guid_prefix.value
    for i in range(1, big.size):
        receiver = auth_for(big, i)
        for d, w in zip(sent[:2], windows[:2], strict=True):
            assert w is not None
            if receiver.tags.slot_of_me(sender_prefix, *w) is not None:
                # and that tag holds: the receiver verifies the datagram
                assert isinstance(receiver.check(sender_prefix, d, addr(0, big), 0.0), Freshness)
                tagged.add(i)
    assert tagged == set(range(1, big.size))  # two datagrams reach every receiver's tag


def test_dispose_carries_tags_and_an_outsiders_is_refused_on_them() -> None:
    sender = auth_for(BUNDLE, 1, epoch=3)
    template = encode_spdp_dispose(
        P[1], sequence_number=9, timestamp=None, authenticator=PLACEHOLDER
    )
    d = sender.seal(template)
    assert tail_window(d) == (0, 3)
    assert auth_for(BUNDLE, 0).check(P[1].value, d, addr(1), 0.0) == Freshness(3, 1)
    forged = seal(template, Freshness(4, 1), Ed25519PrivateKey.generate())
    assert auth_for(BUNDLE, 0).check(P[1].value, forged, addr(1), 0.0) == Refusal.BAD_TAG


@settings(max_examples=300, deadline=None)
@given(st.booleans(), st.integers(min_value=0, max_value=10_000), st.integers(0, 7))
def test_flipping_any_bit_of_a_tagged_datagram_gets_it_refused(
    directed: bool, where: int, bit: int
) -> None:
    sender = auth_for(BUNDLE, 1, epoch=9)
    d = peer_datagram(BUNDLE, 1, auth=sender, destination=P[2] if directed else None)
    flipped = bytearray(d)
    flipped[where % len(d)] ^= 1 << bit
    receiver = auth_for(BUNDLE, 2)
    assert isinstance(receiver.check(P[1].value, bytes(flipped), addr(1), 0.0), Refusal)
    assert receiver.verifier.high(P[1].value) is None  # nothing moved
    assert receiver.check(P[1].value, d, addr(1), 0.0) == Freshness(9, 1)


# ---- persisted replay windows ---------------------------------------------------------


def _changed(auth: SpdpAuth) -> bool:
    return auth.verifier.windows_changed


def test_a_restarted_receiver_with_its_windows_refuses_what_it_had_passed(
    tmp_path: Path,
) -> None:
    sender = auth_for(BUNDLE, 1, epoch=5)
    captured = [peer_datagram(BUNDLE, 1, auth=sender) for _ in range(3)]
    receiver = auth_for(BUNDLE, 0)
    for d in captured[1:]:  # the first one never reached this receiver
        assert isinstance(receiver.check(P[1].value, d, addr(1), 0.0), Freshness)
    assert _changed(receiver)
    path = windows_path(tmp_path, "uav0")
    save_windows(path, receiver.verifier.snapshot())
    # restart: a fresh verifier from the file
    again = auth_for(BUNDLE, 0)
    loaded = load_windows(path)
    assert loaded.problem is None and again.verifier.restore(loaded.highs) == 1
    for d in captured:  # every capture, even the one never seen before the restart
        assert again.check(P[1].value, d, addr(1), 1.0) == Refusal.REPLAYED
    # the live sender goes on above it; its next life too
    assert isinstance(
        again.check(P[1].value, peer_datagram(BUNDLE, 1, auth=sender), addr(1), 1.0), Freshness
    )
    reborn = auth_for(BUNDLE, 1, epoch=6)
    assert again.check(
        P[1].value, peer_datagram(BUNDLE, 1, auth=reborn), addr(1), 1.1
    ) == Freshness(6, 1)


def test_the_window_file_is_bounded_and_a_bad_one_is_reported_not_fatal(tmp_path: Path) -> None:
    highs = {P[1].value: Freshness(5, 9), P[2].value: Freshness(1, 1)}
    assert decode_windows(encode_windows(highs)).highs == highs
    assert load_windows(tmp_path / "missing").problem is None
    bad = tmp_path / "bad"
    bad.write_bytes(encode_windows(highs) + b"zz 1 2\n" + b"\xff")
    loaded = load_windows(bad)
    assert loaded.problem is not None and loaded.highs == {}  # not ASCII: nothing trusted
    bad.write_bytes(encode_windows(highs) + b"nonsense\n" + f"{'ab' * 12} 99999999999 1\n".encode())
    loaded = load_windows(bad)
    assert loaded.problem == "corrupt line 3" and loaded.highs == highs
    huge = tmp_path / "huge"
    huge.write_bytes(b"0" * ((1 << 20) + 1))
    assert load_windows(huge).highs == {}
    # a stranger's prefix in the file is not restored
    receiver = auth_for(BUNDLE, 0)
    assert receiver.verifier.restore({bytes(12): Freshness(1, 1), **highs}) == 2


# ---- engines on a MemNet ----------------------------------------------------------------


def _with_freshness(base: bytes, seq: int) -> bytes:
    """``base`` with the seq half of its freshness rewritten: forgeries at rate without an
    Ed25519 signing each (a forger needs no valid signature to try)."""
    d = bytearray(base)
    n = len(d)
    d[n - 72 : n - 68] = seq.to_bytes(4, "little")
    return bytes(d)


def flood_run(rate: int, seconds: float, *, seed: int = 18) -> tuple[Swarm, list[dict[str, int]]]:
    """A 3-node authenticated swarm (uav0 the commander) converges; then an outsider sends
    ``rate`` forged SPDP a second to each drone for ``seconds``: to each member under the
    commander's prefix from the commander's exact address, to the commander under each
    member's prefix from that member's address (multicast or unicast: an engine sees both
    the same way). Returns the swarm and each engine's drop counters that moved."""
    swarm = build_swarm(3, seed=seed, authenticated=True)
    swarm.run_until(20.0)
    assert swarm.all_discovered() and swarm.lost == 0
    bundle, net = swarm.bundle, swarm.net
    rng = random.Random(seed)
    bases = {i: outsider_forgery(i, 1, rng, bundle) for i in range(3)}

    def deliver(victim: int, claimed: int, seq: int) -> Callable[[float], None]:
        def go(now: float) -> None:
            engine = swarm.engines[victim]
            engine.receive_datagram(
                _with_freshness(bases[claimed], seq), addr(claimed, bundle), now
            )
            net.poke(victim)

        return go

    start, count = 20.0, int(rate * seconds)
    for k in range(count):
        at = start + k / rate
        for victim, claimed in ((1, 0), (2, 0), (0, 1), (0, 2)):
            net.call_at(at, deliver(victim, claimed, k + 2))
    swarm.run_until(start + seconds + 5.0)
    dropped = [{k: v for k, v in e.counters()["dropped"].items() if v} for e in swarm.engines]
    return swarm, dropped


@pytest.mark.parametrize("rate", [100, 2000])
def test_a_spoofed_flood_on_every_drone_loses_no_peer(rate: int) -> None:
    """Issue 18's attack in virtual time: at 100/s (the issue's trickle) and 2,000/s for 60 s
    (a lease is 20 s here), no drone loses anyone, and the refusals are named."""
    swarm, dropped = flood_run(rate, 60.0)
    assert swarm.lost == 0 and swarm.all_discovered()
    sent = int(rate * 60.0)
    for victim, received in ((0, 2 * sent), (1, sent), (2, sent)):
        d = dropped[victim]
        lucky = d.get("auth_bad_signature", 0)  # a random 2-octet tag passes 1 in 65,536
        assert d.get("auth_bad_tag", 0) + lucky == received
        assert lucky <= 10 + received // 16_384  # 4x the expectation
        # nothing else was refused: no budget ran out
        assert set(d) <= {"auth_bad_tag", "auth_bad_signature", "own"}
    assert all(e.counters()["auth"]["verified"] < 200 for e in swarm.engines)


def test_without_the_tags_the_same_flood_loses_the_commander(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The control: with the tag check switched off (each datagram treated as carrying no
    tag for the receiver, as in issue 10), 100 forgeries a second spend the commander's
    budget at the members and they lose it: the test above can fail."""
    monkeypatch.setattr(ReceiverTags, "slot_of_me", lambda self, sender, start, count: None)
    monkeypatch.setattr(ReceiverTags, "may_omit_me", lambda self, sender, count: True)
    swarm, dropped = flood_run(100, 60.0)
    assert swarm.lost > 0
    assert dropped[1].get("auth_budget_sender", 0) > 0


def test_a_restarted_engine_does_not_rediscover_a_dead_member_from_its_capture() -> None:
    """Issue 18: after a receiver restarts, a dead member's captured DATA(p) made it appear
    discovered for a lease. With the windows restored from the state dir it is a replay."""
    bundle = make_bundle(3)
    member = auth_for(bundle, 2, epoch=4)
    captured = peer_datagram(bundle, 2, auth=member)
    commander = auth_for(bundle, 0)
    e = engine_for(bundle, 0, auth=commander)
    e.receive_datagram(captured, addr(2, bundle), 0.1)
    assert any(isinstance(x, PeerDiscovered) for x in iter(e.next_event, None))
    saved = encode_windows(commander.verifier.snapshot())
    # uav2 dies; uav0 restarts (new engine, new verifier) with its state dir
    again = auth_for(bundle, 0, epoch=2)
    again.verifier.restore(decode_windows(saved).highs)
    e2 = engine_for(bundle, 0, auth=again)
    e2.receive_datagram(captured, ("10.0.0.66", 7412), 5.0)
    assert not any(isinstance(x, PeerDiscovered) for x in iter(e2.next_event, None))
    assert e2.counters()["dropped"]["auth_replayed"] == 1
    # the control: without the file the capture discovers the dead member again
    e3 = engine_for(bundle, 0, auth=auth_for(bundle, 0, epoch=3))
    e3.receive_datagram(captured, ("10.0.0.66", 7412), 5.0)
    assert any(isinstance(x, PeerDiscovered) for x in iter(e3.next_event, None))


# ---- a forgery whose tag held: one verification, however often it is sent -------------


def _with_bad_signature(datagram: bytes) -> bytes:
    """``datagram`` with one octet of its Ed25519 signature flipped: every receiver tag still
    holds (the tags do not cover the signature), the signature does not."""
    bad = bytearray(datagram)
    bad[len(bad) - 4 - 10] ^= 0x40  # inside the 64 signature octets before the sentinel
    return bytes(bad)


def test_a_forgery_that_passed_the_tag_costs_one_verification_however_often_it_is_sent() -> None:
    """The spoofed-address attack test's lead drone once counted 214 ``auth_bad_signature``:
    one lucky tag in a pool of 1,400 forgeries, sent 214 times over, each copy spending a
    verification and a token of the real sender's budget. Here the tag holds for certain (a
    genuine datagram's, its signature broken) and the copy is sent 100 times, 2.5 times the
    sender's burst: before the fix the sender's budget ran dry and its next genuine datagram
    was refused."""
    member = auth_for(BUNDLE, 1)
    commander = auth_for(BUNDLE, 0, epoch=5)
    lucky = _with_bad_signature(peer_datagram(BUNDLE, 0, auth=commander))
    verdicts = [member.check(P[0].value, lucky, addr(0), 0.0) for _ in range(100)]
    assert verdicts[0] == Refusal.BAD_SIGNATURE
    assert set(verdicts[1:]) == {Refusal.REPEATED_FORGERY}
    assert member.counters()["verified"] == 1
    # the same instant: the commander's burst less the one token is there for its datagrams
    for _ in range(int(SENDER_BURST) - 1):
        d = peer_datagram(BUNDLE, 0, auth=commander)
        assert isinstance(member.check(P[0].value, d, addr(0), 0.0), Freshness)


def test_a_corrupted_copy_raced_ahead_of_a_genuine_datagram_does_not_get_it_refused() -> None:
    """The table holds whole datagrams, signature included: an attacker who sniffs a genuine
    datagram and gets a corrupted copy processed first costs one verification, and the
    genuine one still passes (it is not the same octets)."""
    member = auth_for(BUNDLE, 1)
    genuine = peer_datagram(BUNDLE, 0, auth=auth_for(BUNDLE, 0, epoch=5))
    for _ in range(5):
        assert member.check(P[0].value, _with_bad_signature(genuine), addr(0), 0.0) in (
            Refusal.BAD_SIGNATURE,
            Refusal.REPEATED_FORGERY,
        )
    assert member.check(P[0].value, genuine, addr(0), 0.0) == Freshness(5, 1)
    assert member.counters()["verified"] == 2


def test_the_failed_datagram_table_is_capped() -> None:
    from swarmd.auth.spdp import MAX_FAILED_DIGESTS

    member = auth_for(BUNDLE, 1)
    sender = auth_for(BUNDLE, 0, epoch=5)
    for k in range(MAX_FAILED_DIGESTS + 40):
        lucky = _with_bad_signature(peer_datagram(BUNDLE, 0, auth=sender))
        assert member.check(P[0].value, lucky, addr(0), float(k)) == Refusal.BAD_SIGNATURE
    assert member.verifier.failed_remembered == MAX_FAILED_DIGESTS
