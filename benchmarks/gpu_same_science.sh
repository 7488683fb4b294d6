#!/usr/bin/env bash
# The GPU's science against the CPU's (run on a GPU machine, from the repo root; see benchmarks/cpu-reference):
#   1. benchmarks/thread_check.py: 4 threads x 50 Newton + Floquet solves, the bits of the same solves in sequence;
#   2. site-bond on the GPU RUNS times, PARALLEL processes at a time: each run's branch points counted;
#   3. python -m scenarios paper --device cuda (JOBS scenes at once).
# Writes everything under OUT (default results-gpu): logs, thread-check.json, site-bond-runs.txt, and
# summaries.tgz (every summary.json), which `python -m scenarios compare` reads after unpacking:
#   tar xzf summaries.tgz && python -m scenarios compare benchmarks/cpu-reference/paper gpu/paper
# Usage: bash benchmarks/gpu_same_science.sh [OUT] [RUNS] [PARALLEL] [JOBS]
set -uo pipefail
out=${1:-results-gpu}
runs=${2:-10}
parallel=${3:-4}
jobs=${4:-auto}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
python3 benchmarks/thread_check.py --out "$out/thread-check.json" > "$out/thread-check-log.txt" 2>&1
echo "thread_check exit $?" | tee -a "$out/site-bond-runs.txt"
for ((i = 1; i <= runs; i++)); do
  (python3 -m scenarios run site-bond --device cuda --out "$out/gpu/site-bond-$i" > "$out/site-bond-$i-log.txt" 2>&1
   echo "site-bond run $i exit $?" >> "$out/site-bond-runs.txt") &
  if ((i % parallel == 0)); then wait; fi
done
wait
for ((i = 1; i <= runs; i++)); do
  python3 - "$out/gpu/site-bond-$i/site-bond/summary.json" "$i" >> "$out/site-bond-runs.txt" <<'EOF'
import json, sys
try:
    s = json.load(open(sys.argv[1]))
except OSError:
    print(f"run {sys.argv[2]}: no summary"); sys.exit()
b = s["bifurcation_points"]
print(f"run {sys.argv[2]}: {sum(1 for x in b if x.get('located', True))} located branch points of {len(b)} records")
EOF
  grep -c "not located\|retrying\|FAILED" "$out/site-bond-$i-log.txt" | sed "s/^/run $i: log lines not located, retried or failed: /" >> "$out/site-bond-runs.txt"
done
python3 -m scenarios paper --device cuda --jobs "$jobs" --out "$out/gpu/paper" > "$out/paper-log.txt" 2>&1
echo "paper exit $?" >> "$out/site-bond-runs.txt"
cat "$out/site-bond-runs.txt"
(cd "$out" && find gpu -name summary.json -o -name failed.json | tar czf summaries.tgz -T -)
