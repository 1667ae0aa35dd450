#!/usr/bin/env bash
# Writes the locks from the ranges in pyproject.toml and lab/pyproject.toml (issue 17):
#   requirements/test.lock           every package `make test` installs, ==version + hashes
#                                     (x86_64 Linux, Python 3.11: the CI and lab machines)
#   requirements/runtime-aarch64.lock the drone's runtime set for a Jetson Nano (aarch64,
#                                     manylinux2014, wheels only), at the test lock's versions
# Without UPGRADE=1 the pins already in a lock are kept and only what pyproject.toml changed is
# resolved again; with UPGRADE=1 every package moves to its newest release in range.
# OUT=dir writes both locks there instead (make test-latest uses it).
set -euo pipefail
cd "$(dirname "$0")/.."
UV=${UV:-.venv/bin/uv}
OUT=${OUT:-requirements}
mkdir -p "$OUT"
[ "$OUT" = requirements ] || cp requirements/test.lock requirements/runtime-aarch64.lock "$OUT"/
upgrade=()
[ -z "${UPGRADE:-}" ] || upgrade=(--upgrade)
common=(--generate-hashes --python-version 3.11 --quiet "${upgrade[@]}")

"$UV" pip compile requirements/test.in -o "$OUT/test.lock" "${common[@]}" \
  --python-platform x86_64-unknown-linux-gnu \
  --no-emit-package swarmd --no-emit-package swarmd-lab \
  --custom-compile-command "make lock"

# the runtime set at exactly the versions the tests ran with: the test lock is the constraint
# (a fixed relative path: it shows in the lock's "via" comments, which must not churn)
pins=.cache/lock/test-pins.txt
mkdir -p "$(dirname "$pins")"
grep -E '^[A-Za-z0-9._-]+==' "$OUT/test.lock" | sed 's/ *\\$//' >"$pins"
"$UV" pip compile pyproject.toml -o "$OUT/runtime-aarch64.lock" "${common[@]}" \
  --python-platform aarch64-manylinux2014 --only-binary :all: --constraint "$pins" \
  --custom-compile-command "make lock"
echo "lock: wrote $OUT/test.lock ($(grep -cE '^[A-Za-z0-9._-]+==' "$OUT/test.lock") packages)" \
  "and $OUT/runtime-aarch64.lock ($(grep -cE '^[A-Za-z0-9._-]+==' "$OUT/runtime-aarch64.lock"))"
