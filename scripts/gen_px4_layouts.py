#!/usr/bin/env python3
"""Generate swarmd/xrce/px4_layouts.py from PX4's message definitions (px4_msgs per release).

    python scripts/gen_px4_layouts.py ../shared/peers/xrce/px4_msgs > swarmd/xrce/px4_layouts.py

PX4's uXRCE-DDS samples are its uORB structs serialised by ``msg/templates/ucdr/msg.h.em``:
fields in .msg order, nested messages flattened, each primitive aligned to its own size from
the payload's first octet, no encapsulation header. Only the fields swarmd reads (or writes,
for VehicleCommand) are emitted, with the payload size and MESSAGE_VERSION that pick the
layout and the topic's ``_vN`` suffix.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

RELEASES = {"1.14": "v1.14.0", "1.15": "v1.15.4", "1.16": "v1.16.0", "1.17": "v1.17.0"}
SIZES = {
    "bool": ("?", 1), "char": ("B", 1), "byte": ("B", 1), "uint8": ("B", 1), "int8": ("b", 1),
    "uint16": ("H", 2), "int16": ("h", 2), "uint32": ("I", 4), "int32": ("i", 4),
    "uint64": ("Q", 8), "int64": ("q", 8), "float32": ("f", 4), "float64": ("d", 8),
}  # fmt: skip
WANT = {
    "VehicleStatus": ["timestamp", "arming_state", "nav_state", "failsafe",
                      "pre_flight_checks_pass", "system_id", "component_id", "vehicle_type"],
    "VehicleLandDetected": ["timestamp", "landed", "maybe_landed", "ground_contact"],
    "FailsafeFlags": None,  # every field: the flags and the per-mode requirement masks
    "BatteryStatus": ["timestamp", "connected", "voltage_v", "remaining"],
    "SensorGps": ["timestamp", "fix_type", "satellites_used", "eph", "lat", "lon", "alt",
                  "latitude_deg", "longitude_deg", "altitude_msl_m"],
    "HomePosition": ["timestamp", "lat", "lon", "alt", "valid_alt", "valid_hpos"],
    "VehicleCommandAck": ["timestamp", "command", "result", "result_param1", "result_param2",
                          "target_system", "target_component", "from_external"],
    "VehicleCommand": None,  # every field: swarmd writes it
}  # fmt: skip


def fields(msg_dir: Path, name: str) -> list[tuple[str, str, int]]:
    out = []
    for raw in (msg_dir / f"{name}.msg").read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        m = re.match(r"^([\w/]+)(?:\[(\d+)\])?\s+(\w+)\s*(=.*)?$", line)
        if not m or m.group(4):
            continue
        out.append((m.group(1).split("/")[-1], m.group(3), int(m.group(2) or 1)))
    return out


def constant(msg_dir: Path, name: str, const: str) -> int:
    text = (msg_dir / f"{name}.msg").read_text()
    m = re.search(rf"^\s*\w+\s+{const}\s*=\s*(\d+)", text, re.M)
    return int(m.group(1)) if m else 0


def layout(msg_dir: Path, name: str, prefix: str = "", offset: int = 0):
    out: dict[str, tuple[int, str, int]] = {}
    for typ, fname, count in fields(msg_dir, name):
        if typ in SIZES:
            code, size = SIZES[typ]
            offset += (-offset) % size
            out[prefix + fname] = (offset, code, count)
            offset += size * count
            continue
        for i in range(count):
            sub = f"{prefix}{fname}{f'[{i}]' if count > 1 else ''}."
            inner, offset = layout(msg_dir, typ, sub, offset)
            out.update(inner)
    return out, offset


def quoted(text: str) -> str:
    return f'"{text}"'  # the house style's quotes (the tables are under fmt: off)


Row = tuple[str, str, list[int | None]]  # name, struct code, offset per release (None: absent)


def merge(per_release: list[list[tuple[str, str, int]]]) -> list[Row]:
    """One row per field across releases, in .msg order: a field keeps its row while its name
    and struct code stay; a renamed or retyped field gets a new row next to where it stands."""
    rows: list[Row] = []
    for i, fields in enumerate(per_release):
        at = 0  # rows before this one are behind this release's previous field
        for k, (name, code, offset) in enumerate(fields):
            j = next((j for j, r in enumerate(rows) if j >= at and r[:2] == (name, code)), None)
            if j is None:  # new in this release: after the rows it replaces, before its next
                ahead = {(n, c) for n, c, _ in fields[k:]}
                while at < len(rows) and rows[at][:2] not in ahead:
                    at += 1
                rows.insert(at, (name, code, [None] * len(per_release)))
                j = at
            rows[j][2][i] = offset
            at = j + 1
    for i, fields in enumerate(per_release):  # each release reads back its own order
        if [(n, c, o[i]) for n, c, o in rows if o[i] is not None] != fields:
            raise SystemExit(f"release {i}: its fields do not merge in .msg order")
    return rows


def main(root: Path) -> None:
    print('"""PX4 uORB message layouts for uXRCE-DDS, per release (generated: do not edit).')
    print()
    print("Made by scripts/gen_px4_layouts.py from px4_msgs at", ", ".join(RELEASES.values()))
    print("(PX4's msg/ definitions, BSD-3-Clause). Per release and message: the CDR payload size,")
    print("MESSAGE_VERSION, and (offset, struct code, count) of the fields swarmd uses.")
    print()
    print("One table per message, a column per release (``px4_table``): its (size,")
    print("MESSAGE_VERSION), then a row per field with its struct code and offset (None: not in")
    print("that release). Reading along a row shows how a field moved between releases;")
    print("``LAYOUTS`` is the same data by release.")
    print('"""')
    print()
    print("from typing import Final")
    print()
    print("from swarmd.xrce.px4_table import Layout, per_release")
    print()
    print("RELEASES: Final = (" + ", ".join(quoted(r) for r in RELEASES) + ")")
    print()
    print("# fmt: off")
    print("_MESSAGES: Final[dict[str, dict[str, Layout]]] = {")
    for name, want in WANT.items():
        heads: list[tuple[int, int]] = []
        per_release: list[list[tuple[str, str, int]]] = []
        for tag in RELEASES.values():
            msg_dir = root / f"px4_msgs-{tag}" / "msg"
            lay, size = layout(msg_dir, name)
            heads.append((size, constant(msg_dir, name, "MESSAGE_VERSION")))
            keep = [(k, c, o) for k, (o, c, n) in lay.items() if want is None or k in want]
            if any(lay[k][2] != 1 for k, _, _ in keep):
                raise SystemExit(f"{name}: an array field (the tables assume count 1)")
            per_release.append(keep)
        rows = merge(per_release)
        width = max(len(n) for n, _, _ in rows) + 3
        cols = "".join(f"{r:>6}" for r in RELEASES)
        print(f'    "{name}": per_release(')
        print("        RELEASES,")
        print(f"        {tuple(heads)!r},  # (size, MESSAGE_VERSION) per release")
        print("        (")
        print(f"            # {'field':<{width}} code{cols}")
        for n, c, offsets in rows:
            cells = "".join(f"{repr(o) + ',':>6}" for o in offsets)
            print(f"            ({quoted(n) + ',':<{width + 1}} {quoted(c)},{cells[:-1]}),")
        print("        ),")
        print("    ),")
    print("}")
    print("# fmt: on")
    print()
    print("LAYOUTS: Final[dict[str, dict[str, Layout]]] = {")
    print("    release: {message: layouts[release] for message, layouts in _MESSAGES.items()}")
    print("    for release in RELEASES")
    print("}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
