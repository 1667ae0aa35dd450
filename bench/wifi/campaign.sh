#!/usr/bin/env bash
# The dilated campaign behind docs/benchmarks.md ("Wireless testbed"), one configuration at
# a time, most important first, so a campaign cut short by END still has its headline runs:
#   1. N=10 (k=3) and N=20 (k=6) repeat 1 of what the session-2 campaign lacks or must redo
#      (today's swarmd; Fast DDS after its reader-limit fix, which binds above 10 members);
#   2. every contender at N=5 undilated (k=1) repeat 1, and swarmd at k=3 (the method's check);
#   3. repeats 2 and 3 of N=10 and N=20 with every contender, then N=5 repeats 2 and 3.
# N=20 runs at k=6 for every contender: at k=4 Fast DDS and zenoh lagged (p99 55-66 ms), and
# swarmd / stock ratios pair runs of the same k and repeat.
# Each step is bounded by `timeout`; the whole by END (epoch seconds, default: 2 h).
#   sudo nohup bench/wifi/campaign.sh > bench/results/wifi-dilated/campaign.log 2>&1 &
# Then: .venv/bin/python bench/wifi/report.py bench/results/wifi-dilated --docs docs/benchmarks.md
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-bench/results/wifi-dilated}
END=${END:-$(( $(date +%s) + 2 * 3600 ))}
ALL=swarmd,cyclonedds,zenoh,fastdds,fastdds-server
mkdir -p "$OUT"
echo "campaign: commit $(git rev-parse --short=10 HEAD), end $(date -u -d "@$END" +%H:%M:%S)"

step() {  # step N K CONTENDERS REPEAT
  local n=$1 k=$2 contenders=$3 repeat=$4
  local count=$(( $(tr ',' '\n' <<< "$contenders" | wc -l) ))
  # per contender: window 60 s x k plus ns-3 import and N stack start-ups (80-90 s measured)
  local need=$(( count * (60 * ${k%.*} + 90) ))
  local bound=$(( need * 2 ))
  if (( $(date +%s) + need > END )); then
    echo "campaign: skipping n=$n k=$k r$repeat $contenders (deadline)"; return
  fi
  echo "campaign: $(date -u +%H:%M:%S) n=$n k=$k r$repeat $contenders"
  timeout --signal=TERM --kill-after=60 "$bound" .venv/bin/python bench/wifi/run.py \
    --n "$n" --dilation "$k" --contenders "$contenders" --first-run "$repeat" --repeat 1 \
    --out "$OUT" --no-report
}

step 10 3 swarmd 1
step 20 6 swarmd,cyclonedds,fastdds,fastdds-server 1
step 5 1 swarmd,zenoh,fastdds-server 1  # fastdds and cyclonedds: r1 from session 2
step 5 3 swarmd 1
for repeat in 2 3; do
  step 10 3 "$ALL" "$repeat"
  step 20 6 "$ALL" "$repeat"
done
for repeat in 2 3; do
  step 5 1 "$ALL" "$repeat"
done
.venv/bin/python bench/wifi/report.py "$OUT"
echo "campaign: done $(date -u +%H:%M:%S)"
