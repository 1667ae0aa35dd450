#!/usr/bin/env bash
# The ROS 2 contenders' campaign (issue 19) behind docs/benchmarks.md "ROS 2 contenders":
# each step runs one repeat of swarmd, stock Fast DDS and the ROS 2 contenders back to back
# (one `run.py` call, same N, k and commit), at the dilation docs/testbed.md prescribes
# (N=5 undilated, N=10 k = 3), repeat 1 of both N first, then further repeats while END
# allows. Repeats are numbered from FIRST (default 4: repeats 1-3 of swarmd and fastdds in
# bench/results/wifi-dilated/runs/ are the session-3 campaign's and stay as they are).
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
  echo "campaign-ros2: $(date -u +%H:%M:%S) n=$n k=$k r$repeat $contenders"
  timeout --signal=TERM --kill-after=60 "$bound" "$PY" bench/wifi/run.py \
    --n "$n" --dilation "$k" --contenders "$contenders" --first-run "$repeat" --repeat 1 \
    --out "$OUT" --no-report
}

for (( r = FIRST; r < FIRST + REPEATS; r++ )); do
  step 5 1 "$ALL" "$r"
  step 10 3 "$ALL" "$r"
done
"$PY" bench/wifi/report.py "$OUT"
echo "campaign-ros2: done $(date -u +%H:%M:%S)"
