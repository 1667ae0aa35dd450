#!/usr/bin/env bash
# Sets up everything `make test` and `make demo` need on a fresh Debian machine:
# the Debian tools the tests drive (tshark, iproute2, nftables, iptables, ...) and a Python 3.11 venv
# with swarmd installed editable plus its dev extra, and the lab tools (lab/) editable.
# Idempotent; quiet when nothing is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
APT_PACKAGES=(tshark iproute2 nftables iptables procps openssh-server openssh-client systemd
  gcc g++ libfastrtps-dev libfastcdr-dev fastdds-tools)
# what proves each package is present (same order as APT_PACKAGES): a command, or a file
# for a library; gcc (the time-dilation library), g++, libfastrtps-dev/libfastcdr-dev and
# fastdds-tools: the Wi-Fi testbed's Fast DDS contenders (bench/wifi/native.py, our own code);
# iptables-legacy-restore: swarmd local-firewall's iptables backend as on the Jetson Nano
# (tests/test_local_firewall_netns.py)
APT_PROBES=(tshark ip nft iptables-legacy-restore pgrep sshd ssh systemd-analyze
  gcc g++ /usr/include/fastdds/rtps/RTPSDomain.h /usr/include/fastcdr/Cdr.h fastdds)

missing=()
for i in "${!APT_PACKAGES[@]}"; do
  probe=${APT_PROBES[$i]}
  if [[ $probe == /* ]]; then
    [ -e "$probe" ] || missing+=("${APT_PACKAGES[$i]}")
    continue
  fi
  if ! command -v "$probe" >/dev/null 2>&1 && [ ! -x "/usr/sbin/$probe" ]; then
    missing+=("${APT_PACKAGES[$i]}")
  fi
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing Debian packages: ${missing[*]}"
  if [ "$(id -u)" -ne 0 ]; then
    echo "setup: need root for apt-get (missing: ${missing[*]}); rerun as root or install them" >&2
    exit 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  apt-get -o DPkg::Lock::Timeout=600 update -qq
  # wireshark-common asks whether non-root users may capture: preseed "no" so the install never prompts
  echo "wireshark-common wireshark-common/install-setuid boolean false" | debconf-set-selections
  apt-get install -o DPkg::Lock::Timeout=600 -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=""
for cand in python3.11 python3; do
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
    PY=$(command -v "$cand"); break
  fi
done
[ -n "$PY" ] || { echo "setup: Python >= 3.11 not found on PATH" >&2; exit 1; }

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating venv $VENV with $PY"
  "$PY" -m venv "$VENV"
fi
# Everything the venv holds comes from requirements/test.lock: every package of the test
# environment at one version, with its hashes (pip's hash-checking mode), so a fresh clone gets
# exactly what CI got and a new release upstream cannot turn `make test` red (issue 17). The
# two local distributions go in afterwards without resolving anything: swarmd (what flies) and
# swarmd-lab (lab/: simulator, demo, namespaces, vehicle stand-ins), both editable, built with
# the locked setuptools (no build isolation, so no unpinned build backend is fetched).
# `make lock` refreshes the lock; `make test-latest` runs the suite against the newest releases.
LOCK=${LOCK:-requirements/test.lock}
stamp="$VENV/.installed"
want=$(cat "$LOCK" pyproject.toml lab/pyproject.toml | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "setup: pip install --require-hashes -r $LOCK, then -e . -e ./lab"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps \
    --require-hashes -r "$LOCK"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --no-deps \
    --no-build-isolation -e . -e ./lab
  "$VENV/bin/python" -m pip check >/dev/null || {
    "$VENV/bin/python" -m pip check >&2
    echo "setup: $LOCK does not satisfy pyproject.toml's dependencies: run 'make lock'" >&2
    exit 1
  }
  echo "$want" >"$stamp"
fi

# Third-party XRCE-DDS peers (PX4's client library, eProsima's MicroXRCEAgent) are never
# built here: ../shared/peers/xrce holds data only (message definitions, a recorded session).
# Tests that drive those binaries run when XRCE_PEERS names a directory holding them, built
# elsewhere, and skip with that reason otherwise (tests/xrce_peers.py); everything else runs
# against our own PX4 stand-in (lab/swarmd_lab/px4/).

# the Wi-Fi testbed's native pieces (Fast DDS peer, time-dilation library) into
# .cache/bench-wifi, rebuilt only when a source changed; a failure only disables those
# contenders and --dilation (their tests skip with the reason)
"$VENV/bin/python" -m bench.wifi.native || echo "setup: bench/wifi native pieces not built (see above)" >&2
