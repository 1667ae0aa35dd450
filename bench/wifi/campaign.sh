#!/usr/bin/env bash
# The dilated campaign behind docs/benchmarks.md ("Wireless testbed"), one configuration at
# a time, most important first, so a campaign cut short still has its headline runs:
#   1. the method's check at N=5: undilated (k=1) and dilated (k=3) back to back;
#   2. every contender at N=10 (k=3) and N=20 (k=4);
#   3. repeats 2 and 3 of the same, while time is left.
# Each step is bounded by `timeout`; the whole by END (epoch seconds, default: 3 h).
#   sudo nohup bench/wifi/campaign.sh > bench/results/wifi-dilated/campaign.log 2>&1 &
# Then: .venv/bin/python bench/wifi/report.py bench/results/wifi-dilated
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-bench/results/wifi-dilated}
END=${END:-$(( $(date +%s) + 3 * 3600 ))}
ALL=swarmd,cyclonedds,zenoh,fastdds,fastdds-server
mkdir -p "$OUT"

step() {  # step N K CONTENDERS REPEAT
  local n=$1 k=$2 contenders=$3 repeat=$4
  local count=$(( $(tr ',' '\n' <<< "$contenders" | wc -l) ))
  # a generous per-run bound: window 60 s x k, ns-3 import, N imports at nice 10
  local bound=$(( count * (60 * ${k%.*} + 240) ))
  if (( $(date +%s) + bound / 2 > END )); then
    echo "campaign: skipping n=$n k=$k r$repeat $contenders (deadline)"; return
  fi
  echo "campaign: $(date -u +%H:%M:%S) n=$n k=$k r$repeat $contenders"
  timeout --signal=TERM --kill-after=60 "$bound" .venv/bin/python bench/wifi/run.py \
    --n "$n" --dilation "$k" --contenders "$contenders" --first-run "$repeat" --repeat 1 \
    --out "$OUT" --no-report
}

for repeat in 1 2 3; do
  step 5 1 fastdds,cyclonedds,swarmd "$repeat"
  step 5 3 fastdds,cyclonedds,swarmd "$repeat"
  step 10 3 "$ALL" "$repeat"
  step 20 4 "$ALL" "$repeat"
  step 5 1 zenoh,fastdds-server "$repeat"
  step 5 3 zenoh,fastdds-server "$repeat"
done
.venv/bin/python bench/wifi/report.py "$OUT"
echo "campaign: done $(date -u +%H:%M:%S)"
