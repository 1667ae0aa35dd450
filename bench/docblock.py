"""A generated block in a docs file: the lines between two HTML-comment markers, rewritten by
the benchmark that measured them (``bench/flood.py --write-docs``, ``bench/spoof.py
--write-docs``); everything outside the markers is kept as it is."""

from __future__ import annotations

from pathlib import Path


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
