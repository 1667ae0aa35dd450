"""bench/docblock.py: a benchmark's generated block replaces only its own lines."""

from __future__ import annotations

from pathlib import Path

from bench.docblock import write_block

BEGIN = "<!-- x:begin (bench/x.py --write-docs) -->"
END = "<!-- x:end -->"


def test_the_block_between_the_markers_is_replaced_and_nothing_else(tmp_path: Path) -> None:
    docs = tmp_path / "b.md"
    docs.write_text(f"# head\n\n{BEGIN}\nold 1\nold 2\n{END}\n\ntail <!-- y:end -->\n")
    write_block(docs, BEGIN, END, f"{BEGIN}\nnew\n{END}")
    assert docs.read_text() == f"# head\n\n{BEGIN}\nnew\n{END}\n\ntail <!-- y:end -->\n"


def test_a_file_without_the_markers_gets_the_block_appended(tmp_path: Path) -> None:
    docs = tmp_path / "b.md"
    docs.write_text("# head\n\n\n")
    write_block(docs, BEGIN, END, f"{BEGIN}\nnew\n{END}")
    assert docs.read_text() == f"# head\n\n{BEGIN}\nnew\n{END}\n"
