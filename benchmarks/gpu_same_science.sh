#!/usr/bin/env bash
# The GPU's science against the CPU's (run on a GPU machine, from the repo root; CPU reference: benchmarks/results/):
#   thread: benchmarks/thread_check.py (4 threads x 50 Newton + Floquet solves: the bits of the same solves in sequence)
#   paper:  python -m scenarios paper --device cuda (JOBS scenes at once)
#   site:   site-bond on the GPU, runs FIRST..LAST, PARALLEL processes at a time, each run's branch points counted
# Usage: STEPS="thread paper site" JOBS=auto bash benchmarks/gpu_same_science.sh OUT FIRST LAST PARALLEL
# Writes under OUT: logs, thread-check.json, runs.txt and summaries-FIRST-LAST.tgz (every summary.json and
# failed.json), which `python -m scenarios compare` reads once unpacked:
#   tar xzf summaries-1-4.tgz && python benchmarks/results/compact.py compare \
#     benchmarks/results/cpu-2core-2026-11-25b.json gpu/paper   # or a CPU paper run of the same commit
set -uo pipefail
out=${1:-results-gpu}
first=${2:-1}
last=${3:-10}
parallel=${4:-4}
steps=${STEPS:-thread paper site}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
if [[ $steps == *thread* ]]; then
  python3 benchmarks/thread_check.py --out "$out/thread-check.json" > "$out/thread-check-log.txt" 2>&1
  echo "thread_check exit $?" >> "$out/runs.txt"
fi
if [[ $steps == *paper* ]]; then
  python3 -m scenarios paper --device cuda --jobs "${JOBS:-auto}" --out "$out/gpu/paper" > "$out/paper-log.txt" 2>&1
  echo "paper exit $?" >> "$out/runs.txt"
fi
if [[ $steps == *site* ]]; then
  for ((i = first; i <= last; i++)); do
    (python3 -m scenarios run site-bond --device cuda --out "$out/gpu/site-bond-$i" > "$out/site-bond-$i-log.txt" 2>&1
     echo "site-bond run $i exit $?" >> "$out/runs.txt") &
    if (((i - first + 1) % parallel == 0)); then wait; fi
  done
  wait
  for ((i = first; i <= last; i++)); do
    python3 - "$out/gpu/site-bond-$i/site-bond/summary.json" "$i" "$out/site-bond-$i-log.txt" >> "$out/runs.txt" <<'EOF'
import json, sys
log = open(sys.argv[3]).read()
lines = sum(log.count(w) for w in ("not located", "retrying", "FAILED", "Error"))
try:
    b = json.load(open(sys.argv[1]))["bifurcation_points"]
except OSError:
    print(f"site-bond run {sys.argv[2]}: no summary; {lines} log lines not located / retried / failed")
    sys.exit()
located = sum(1 for x in b if x.get("located", True))
print(f"site-bond run {sys.argv[2]}: {located} located branch points ({len(b)} records); {lines} log lines not located / retried / failed")
EOF
  done
fi
cat "$out/runs.txt"
(cd "$out" && find gpu \( -name summary.json -o -name failed.json \) | tar czf "summaries-$first-$last.tgz" -T -)
