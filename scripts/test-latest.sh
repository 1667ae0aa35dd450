#!/usr/bin/env bash
# The suite against the newest releases every range in pyproject.toml admits (issue 17), in
# its own venv (.venv-latest), so drift upstream shows up here, as a deliberate change,
# before it can show up as a red CI. The committed locks are not touched: if the run is
# green, adopt the new lock with `make lock UPGRADE=1` and commit it.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh  # the locked venv brings uv
OUT=.cache/latest UPGRADE=1 bash scripts/lock.sh
echo "test-latest: what moved against requirements/test.lock:"
diff <(grep -E '^[A-Za-z0-9._-]+==' requirements/test.lock | sed 's/ *\\$//') \
  <(grep -E '^[A-Za-z0-9._-]+==' .cache/latest/test.lock | sed 's/ *\\$//') || true
VENV=.venv-latest LOCK=.cache/latest/test.lock bash scripts/setup.sh
make --no-print-directory test VENV=.venv-latest LOCK=.cache/latest/test.lock
echo "test-latest: green against the newest releases; adopt with: make lock UPGRADE=1"
