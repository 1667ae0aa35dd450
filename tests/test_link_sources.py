"""wext, file and static link sources, and the paper's Q equations."""

from __future__ import annotations

import asyncio
import json
import os
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmd.discovery.inputs import LinkSample
from swarmd.link import quality
from swarmd.link.file import FileSource, sample_from_json
from swarmd.link.source import LinkUnavailable
from swarmd.link.static import StaticSource
from swarmd.link.wext import WextSource, parse_proc_net_wireless

PROC_NET_WIRELESS = """\
Inter-| sta-|   Quality        |   Discarded packets               | Missed | WE
 face | tus | link level noise |  nwid  crypt   frag  retry   misc | beacon | 22
 wlan0: 0000   49.  -61.  -256        0      0      0     12      0        0
 wlan1: 0000   35   195   160        0      0      0      0      0        0
 bogus: 0000   x.  -61.  -256        0      0      0     12      0        0
"""


def test_paper_eq1_and_eq2() -> None:
    assert quality.q_from_lq(49, 70) == pytest.approx(0.7)
    assert quality.q_from_lq(80, 70) == 1.0
    assert quality.q_from_snr(30, floor_db=0) == pytest.approx(0.75)  # garbled print: SNR / 40
    assert quality.q_from_snr(32.5) == pytest.approx(0.5)  # eq. 2: (SNR - 25) / 15
    assert quality.q_from_snr(-3) == 0.0
    assert quality.q_from_snr(55) == 1.0
    with pytest.raises(ValueError, match="empty"):
        quality.q_from_snr(30, floor_db=40)


def test_cfg80211_signal_mapping() -> None:
    assert quality.lq_from_signal(-61) == 49
    assert quality.lq_from_signal(-30) == 70
    assert quality.lq_from_signal(-120) == 0


@given(
    st.floats(-200, 100, allow_nan=False),
    st.one_of(st.none(), st.floats(-200, 100, allow_nan=False)),
)
def test_q_always_in_unit_interval(signal: float, noise: float | None) -> None:
    sample = quality.sample_from_signal(signal, noise, source="x")
    assert 0.0 <= sample.q <= 1.0


def test_parse_proc_net_wireless() -> None:
    entries = parse_proc_net_wireless(PROC_NET_WIRELESS)
    assert set(entries) == {"wlan0", "wlan1"}
    assert (entries["wlan0"].quality, entries["wlan0"].level_dbm) == (49.0, -61.0)
    assert entries["wlan0"].noise_dbm is None  # cfg80211's -256 = unknown
    # a legacy driver printing dBm as unsigned bytes
    assert (entries["wlan1"].level_dbm, entries["wlan1"].noise_dbm) == (-61.0, -96.0)


def test_wext_source(tmp_path: Path) -> None:
    path = tmp_path / "wireless"
    path.write_text(PROC_NET_WIRELESS)
    sample = asyncio.run(WextSource("wlan0", path=str(path)).read())
    assert sample.q == pytest.approx(0.7)
    assert (sample.signal_dbm, sample.snr_db, sample.source) == (-61.0, None, "wext")
    legacy = asyncio.run(WextSource("wlan1", path=str(path)).read())
    assert legacy.snr_db == 35.0
    with pytest.raises(LinkUnavailable, match="not associated") as info:
        asyncio.run(WextSource("wlan9", path=str(path)).read())
    assert not info.value.permanent
    with pytest.raises(LinkUnavailable, match="wireless extensions") as info:
        asyncio.run(WextSource("wlan0", path=str(tmp_path / "missing")).read())
    assert info.value.permanent


@pytest.mark.parametrize(
    ("obj", "q", "snr"),
    [
        ({"q": 0.8}, 0.8, None),
        ({"lq": 35, "lq_max": 70}, 0.5, None),
        ({"snr_db": 20.0}, 0.5, 20.0),
        ({"signal_dbm": -60, "noise_dbm": -90}, 0.75, 30.0),
        ({"signal_dbm": -75}, 0.5, None),
    ],
)
def test_file_shapes(obj: dict[str, float], q: float, snr: float | None) -> None:
    sample = sample_from_json(obj)
    assert sample.q == pytest.approx(q)
    assert sample.snr_db == snr
    assert sample.source == "file"


@pytest.mark.parametrize(
    ("obj", "message"),
    [
        ([1, 2], "JSON object"),
        ({"q": 1.5}, r'"q" must be in \[0, 1\]'),
        ({"q": "high"}, '"q" must be a finite number'),
        ({"q": True}, '"q" must be a finite number'),
        ({"lq": 3}, "lq_max"),
        ({}, "no reading"),
    ],
)
def test_file_bad_content_names_the_key(obj: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        sample_from_json(obj)


def test_file_source(tmp_path: Path) -> None:
    path = tmp_path / "link.json"
    src = FileSource(str(path), max_age_s=60)
    with pytest.raises(LinkUnavailable, match="does not exist"):
        asyncio.run(src.read())
    path.write_text("{not json")
    with pytest.raises(LinkUnavailable, match=str(path)):
        asyncio.run(src.read())
    path.write_text(json.dumps({"q": 0.25}))
    assert asyncio.run(src.read()).q == 0.25
    old = path.stat().st_mtime - 3600
    os.utime(path, (old, old))
    with pytest.raises(LinkUnavailable, match="stale") as info:
        asyncio.run(src.read())
    assert not info.value.permanent


def test_static_source() -> None:
    assert asyncio.run(StaticSource(0.4).read()) == LinkSample(q=0.4, source="static")
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        StaticSource(1.2)
