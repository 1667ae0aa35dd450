#!/usr/bin/env bash
# Sets up everything `make test` and `make demo` need on a fresh Debian machine:
# the Debian tools the tests drive (tshark, iproute2, nftables, ...) and a Python 3.11 venv
# with swarmd installed editable plus its dev extra, and the lab tools (lab/) editable.
# Idempotent; quiet when nothing is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
APT_PACKAGES=(tshark iproute2 nftables procps openssh-server openssh-client systemd
  cmake ninja-build gcc libfastrtps-dev libfastcdr-dev libspdlog-dev g++ fastdds-tools)
# what proves each package is present (same order as APT_PACKAGES): a command, or a file
# for the libraries the XRCE-DDS peers (MicroXRCEAgent) build against; g++ and
# fastdds-tools (with libfastrtps-dev): the Wi-Fi testbed's Fast DDS contenders
APT_PROBES=(tshark ip nft pgrep sshd ssh systemd-analyze
  cmake ninja gcc /usr/include/fastdds/rtps/RTPSDomain.h /usr/include/fastcdr/Cdr.h
  /usr/include/spdlog/spdlog.h g++ fastdds)

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
stamp="$VENV/.installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ lab/pyproject.toml -nt "$stamp" ]; then
  # two distributions, both editable: swarmd (what flies) and swarmd-lab (lab/: simulator,
  # demo, namespaces, vehicle simulator), which depends on swarmd and brings numpy/matplotlib
  echo "setup: pip install -e '.[dev,testbed]' -e ./lab"
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip
  "$VENV/bin/python" -m pip install -q --disable-pip-version-check -e '.[dev,testbed]' -e ./lab
  touch "$stamp"
fi

# The XRCE-DDS test peers (issue 12): PX4's client library with px4_like_client and
# cmd_sender, and eProsima's MicroXRCEAgent, built from ../shared/peers/xrce (beside the
# clone) into the gitignored .cache/xrce. build.sh keeps what is already built; the stamp
# skips even calling it. Tests skip only when the peers directory itself is absent.
# A git worktree's shared/ sits beside the main checkout, found through the common git dir.
if [ -z "${XRCE_PEERS:-}" ]; then
  XRCE_PEERS=../shared/peers/xrce
  common=$(git rev-parse --git-common-dir 2>/dev/null || true)
  if [ ! -d "$XRCE_PEERS" ] && [ -n "$common" ] && [ -d "$common/../../shared/peers/xrce" ]; then
    XRCE_PEERS=$common/../../shared/peers/xrce
  fi
fi
XRCE_OUT=${XRCE_OUT:-.cache/xrce}
if [ -x "$XRCE_PEERS/build.sh" ]; then
  if [ ! -x "$XRCE_OUT/bin/px4_like_client" ] || [ ! -x "$XRCE_OUT/bin/MicroXRCEAgent" ]; then
    echo "setup: building the XRCE-DDS peers from $XRCE_PEERS into $XRCE_OUT (agent: ~2 min)"
    "$XRCE_PEERS/build.sh" "$XRCE_OUT" --agent >/dev/null
  fi
else
  echo "setup: $XRCE_PEERS not found; XRCE-DDS peer tests will skip"
fi

# the Wi-Fi testbed's native pieces (Fast DDS peer, time-dilation library) into
# .cache/bench-wifi, rebuilt only when a source changed; a failure only disables those
# contenders and --dilation (their tests skip with the reason)
"$VENV/bin/python" -m bench.wifi.native || echo "setup: bench/wifi native pieces not built (see above)" >&2
