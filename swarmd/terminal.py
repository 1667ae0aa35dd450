"""Make remote strings safe for a terminal (issue 10 attack 8, style.md rule 17).

Everything ``swarmctl`` prints in its human views, and the daemon's console log
(``swarmd.logs``, when run on a terminal), can come from another host: a foreign
participant's ENTITY_NAME, a member's readiness or outcome reason, anything the vehicle
named. Printed raw, ``ESC [ 2 J`` clears the operator's screen, an OSC sequence retitles the
window, a C1 CSI (U+009B) does the same on terminals that honour 8-bit controls, and a bidi
override (U+202E) makes ``uav2 ready`` read as something else. So every character that is
not printable text is shown as a visible escape instead: ``\\x1b``, ``\\x9b``, ``\\u202e``;
a backslash is doubled so an escape on screen always means one was made.

Escaped: C0 and C1 controls and DEL (Unicode category Cc, tab and newline included: a
table cell is one line), format characters (Cf: bidi embeddings, overrides and isolates,
zero-width joiners, the BOM), line and paragraph separators (Zl, Zp), surrogates (Cs),
private use (Co) and unassigned code points (Cn). ``--json`` output is not touched: it keeps
the exact value, and ``json.dumps`` (``ensure_ascii``) writes those characters as ``\\uXXXX``;
so do the daemon's JSON log lines.
"""

from __future__ import annotations

import unicodedata
from typing import Any, Final

UNSAFE_CATEGORIES: Final = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs", "Co", "Cn"})


def _escape(ch: str) -> str:
    code = ord(ch)
    if code <= 0xFF:
        return f"\\x{code:02x}"
    if code <= 0xFFFF:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def safe_text(text: str) -> str:
    """``text`` with every non-printable character shown as a visible escape."""
    if text.isascii() and text.isprintable() and "\\" not in text:
        return text  # the common case: bundle names, reason codes
    out = []
    for ch in text:
        if ch == "\\":
            out.append("\\\\")
        elif unicodedata.category(ch) in UNSAFE_CATEGORIES:
            out.append(_escape(ch))
        else:
            out.append(ch)
    return "".join(out)


def safe_tree(value: Any) -> Any:
    """A copy of a JSON-like value with every string (keys included) made safe."""
    if isinstance(value, str):
        return safe_text(value)
    if isinstance(value, dict):
        return {safe_tree(k): safe_tree(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [safe_tree(v) for v in value]
    return value
