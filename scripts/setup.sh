#!/usr/bin/env bash
# Sets up everything `make test` and `make demo` need on a fresh Debian machine:
# the Debian tools the tests drive (tshark, iproute2, nftables, ...) and a Python 3.11 venv
# with swarmd installed editable plus its dev extra, and the lab tools (lab/) editable.
# Idempotent; quiet when nothing is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
APT_PACKAGES=(tshark iproute2 nftables procps openssh-server openssh-client systemd)
# command that proves each package is present (same order as APT_PACKAGES)
APT_PROBES=(tshark ip nft pgrep sshd ssh systemd-analyze)

missing=()
for i in "${!APT_PACKAGES[@]}"; do
  probe=${APT_PROBES[$i]}
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
  apt-get update -qq
  # wireshark-common asks whether non-root users may capture: preseed "no" so the install never prompts
  echo "wireshark-common wireshark-common/install-setuid boolean false" | debconf-set-selections
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
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
