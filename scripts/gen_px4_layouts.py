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


def main(root: Path) -> None:
    print('"""PX4 uORB message layouts for uXRCE-DDS, per release (generated: do not edit).')
    print()
    print("Made by scripts/gen_px4_layouts.py from px4_msgs at", ", ".join(RELEASES.values()))
    print("(PX4's msg/ definitions, BSD-3-Clause). Per release and message: the CDR payload size,")
    print("MESSAGE_VERSION, and (offset, struct code, count) of the fields swarmd uses.")
    print('"""')
    print()
    print("from typing import Final")
    print()
    print("Field = tuple[int, str, int]")
    print("Layout = tuple[int, int, dict[str, Field]]  # size, MESSAGE_VERSION, fields")
    print()
    # each distinct layout once (most messages do not change between releases)
    names: dict[str, str] = {}
    table: dict[str, dict[str, str]] = {}
    for release, tag in RELEASES.items():
        msg_dir = root / f"px4_msgs-{tag}" / "msg"
        table[release] = {}
        for name, want in WANT.items():
            lay, size = layout(msg_dir, name)
            version = constant(msg_dir, name, "MESSAGE_VERSION")
            keep = {k: v for k, v in lay.items() if want is None or k in want}
            text = repr((size, version, keep))
            if text not in names:
                names[text] = f"{name.upper()}_{release.replace('.', '_')}"
                print(f"{names[text]}: Final[Layout] = {text}")
            table[release][name] = names[text]
    print()
    print("LAYOUTS: Final[dict[str, dict[str, Layout]]] = {")
    for release, msgs in table.items():
        inner = ", ".join(f'"{m}": {c}' for m, c in msgs.items())
        print(f'    "{release}": {{{inner}}},')
    print("}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
