"""A generated block in a docs file: the lines between two HTML-comment markers, rewritten by
the benchmark that measured them (``bench/flood.py --write-docs``, ``bench/spoof.py
--write-docs``); everything outside the markers is kept as it is. ``head_commit`` names the
commit a result was measured at."""

from __future__ import annotations

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def head_commit() -> str:
    """The checkout's short HEAD commit, or ``unknown`` (no git, not a checkout)."""
    proc = subprocess.run(  # noqa: S603 - fixed argv
        ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],  # noqa: S607
        capture_output=True,
        text=True,
        check=False,
    )
    return proc.stdout.strip() or "unknown"


def write_block(docs: Path, begin: str, end: str, block: str) -> None:
    """Replace ``begin`` ... ``end`` (both inside ``block``) in ``docs``, or append ``block``
    when the file has no such markers yet."""
    text = docs.read_text()
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    docs.write_text(text)
