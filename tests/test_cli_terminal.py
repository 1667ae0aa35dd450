"""Remote strings reach the operator's terminal as visible escapes (issue 10, attack 8)."""

from __future__ import annotations

import io
import json
import unicodedata

from hypothesis import given
from hypothesis import strategies as st

from swarmd.cli.status_cmd import _print_status, render_peers, render_status
from swarmd.cli.takeoff_cmd import render_outcomes
from swarmd.terminal import UNSAFE_CATEGORIES, safe_text, safe_tree

CLEAR_AND_RETITLE = "\x1b[2J\x1b[H\x1b]0;owned\x07"
HOSTILE = f"{CLEAR_AND_RETITLE}uav9\x9b31m\u202eydaer\r\x00\u2028"


def _unsafe(text: str) -> list[str]:
    return [c for c in text if unicodedata.category(c) in UNSAFE_CATEGORIES and c != "\n"]


def test_escape_sequences_become_visible() -> None:
    assert safe_text("\x1b[2J") == "\\x1b[2J"
    assert safe_text("\x9b31m") == "\\x9b31m"
    assert safe_text("abc\u202edef") == "abc\\u202edef"
    assert safe_text("a\tb\nc\rd\x7f") == "a\\x09b\\x0ac\\x0dd\\x7f"
    assert safe_text("\U000e0001") == "\\U000e0001"  # a tag character (Cf) beyond the BMP


def test_printable_text_is_unchanged() -> None:
    for text in ("uav1", "drone-01", "prearm_failed", "Eclipse Cyclone DDS", "Grüße", "ドローン"):
        assert safe_text(text) == text


def test_backslash_is_doubled_so_escapes_are_unambiguous() -> None:
    # the name that *looks* like an escape is told apart from a real ESC
    assert safe_text("\\x1b") == "\\\\x1b"
    assert safe_text("\x1b") != safe_text("\\x1b")


@given(st.text())
def test_any_text_comes_out_printable_and_distinct(text: str) -> None:
    shown = safe_text(text)
    assert _unsafe(shown) == []
    assert "\n" not in shown  # one cell stays one line
    assert safe_text(text + "\x1b") != shown


def test_safe_tree_reaches_keys_and_nested_values() -> None:
    tree = {"\x1bk": [{"name": "\x07"}, 3, None, True]}
    assert safe_tree(tree) == {"\\x1bk": [{"name": "\\x07"}, 3, None, True]}


STATUS = {
    "node": "uav1",
    "peers": [{"name": "uav2", "state": "discovered", "locator": HOSTILE}],
    "foreign": [{"guid": "0a0b:1c1", "vendor": HOSTILE, "name": HOSTILE}],
    "counters": {"dropped": {HOSTILE: 1}},
    "px4": {"enabled": True, "readiness": {"ready": False, "reason": HOSTILE, "detail": HOSTILE}},
    "readiness": {HOSTILE: {"ready": False, "reason": HOSTILE, "landed_state": HOSTILE}},
}


def test_status_view_has_no_control_characters() -> None:
    text = "\n".join(render_status(STATUS))
    assert _unsafe(text) == []
    assert "\\x1b[2J" in text and "\\u202e" in text


def test_peers_and_outcomes_views_have_no_control_characters() -> None:
    assert _unsafe("\n".join(render_peers(STATUS["peers"]))) == []  # type: ignore[arg-type]
    snap = {"nodes": {HOSTILE: {"state": HOSTILE, "reason": HOSTILE, "latency_s": 0.01}}}
    assert _unsafe("\n".join(render_outcomes(snap))) == []


def test_json_keeps_the_exact_value_escaped() -> None:
    out = io.StringIO()
    _print_status(STATUS, True, out)
    raw = out.getvalue()
    assert _unsafe(raw.replace("\n", "")) == []  # JSON-escaped on the wire ...
    assert json.loads(raw)["foreign"][0]["name"] == HOSTILE  # ... and exact when parsed
