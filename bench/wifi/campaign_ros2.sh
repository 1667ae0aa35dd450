#!/usr/bin/env bash
# The ROS 2 contenders' campaign (issue 19) behind docs/benchmarks.md "ROS 2 contenders":
# each step runs one repeat of swarmd, stock Fast DDS and the ROS 2 contenders back to back
# (one `run.py` call, same N, k and commit), at the dilation docs/testbed.md prescribes
# (N=5 undilated, N=10 k = 3, N=20 k = 6), repeat by repeat while END allows. Repeats are
# numbered from FIRST (default 4: repeats 1-3 of swarmd and fastdds in
# bench/results/wifi-dilated/runs/ are the session-3 campaign's and stay as they are).
# STEPS lists the steps of one repeat as N:K:CONTENDERS, e.g.
#   STEPS="20:6:ros2,ros2-ds,ros2-static,ros2-swarmd 5:1:ros2,ros2-swarmd"
# PULL=<branch>: fast-forward the checkout to that branch before each step (never during one),
# so a long campaign from a pinned clone can take a fix between steps; every run file records
# the commit it measured and a ratio pairs only runs of one step.
#   sudo nohup bench/wifi/campaign_ros2.sh > bench/results/wifi-dilated/campaign-ros2.log 2>&1 &
# Then: .venv/bin/python bench/wifi/report.py bench/results/wifi-dilated --docs docs/benchmarks.md
# PY (default .venv/bin/python) and OUT may point elsewhere, e.g. when run from a clean clone.
set -uo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-.venv/bin/python}
OUT=${OUT:-bench/results/wifi-dilated}
END=${END:-$(( $(date +%s) + 3600 ))}
FIRST=${FIRST:-4}
REPEATS=${REPEATS:-3}
ALL=${CONTENDERS:-swarmd,fastdds,ros2,ros2-ds,ros2-static,ros2-swarmd}
STEPS=${STEPS:-"5:1:$ALL 10:3:$ALL"}
PULL=${PULL:-}
mkdir -p "$OUT"
echo "campaign-ros2: commit $(git rev-parse --short=10 HEAD), end $(date -u -d "@$END" +%H:%M:%S)"

step() {  # step N K CONTENDERS REPEAT
  local n=$1 k=$2 contenders=$3 repeat=$4
  local count=$(( $(tr ',' '\n' <<< "$contenders" | wc -l) ))
  # per contender: window 60 s x k plus ns-3 import and N stack start-ups (60-90 s measured)
  local need=$(( count * (60 * ${k%.*} + 60) ))
  local bound=$(( need * 2 ))
  if (( $(date +%s) + need > END )); then
    echo "campaign-ros2: skipping n=$n k=$k r$repeat $contenders (deadline)"; return
  fi
  if [ -n "$PULL" ]; then
    git pull -q --ff-only origin "$PULL" || echo "campaign-ros2: pull of $PULL failed; staying"
  fi
  echo "campaign-ros2: $(date -u +%H:%M:%S) n=$n k=$k r$repeat $contenders at $(git rev-parse --short=10 HEAD)"
  timeout --signal=TERM --kill-after=60 "$bound" "$PY" bench/wifi/run.py \
    --n "$n" --dilation "$k" --contenders "$contenders" --first-run "$repeat" --repeat 1 \
    --out "$OUT" --no-report
}

for (( r = FIRST; r < FIRST + REPEATS; r++ )); do
  for spec in $STEPS; do
    IFS=: read -r n k contenders <<< "$spec"
    step "$n" "$k" "$contenders" "$r"
  done
done
"$PY" bench/wifi/report.py "$OUT"
echo "campaign-ros2: done $(date -u +%H:%M:%S)"
