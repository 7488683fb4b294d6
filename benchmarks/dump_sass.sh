#!/usr/bin/env bash
# SASS of the Verlet kernels in this machine's kernel caches, for comparing the time loops: every Warp
# site-group kernel (warp-group.sass, one header per kernel: its launch bounds and cache folder) and every
# hand-written CUDA kernel from CuPy's cache (hand.sass). Run on the GPU machine after
# benchmarks/sites_per_thread.py: bash benchmarks/dump_sass.sh OUTDIR
set -uo pipefail
out=${1:-.}
co=$(command -v cuobjdump || echo /usr/local/cuda/bin/cuobjdump)
: > "$out/warp-group.sass"
for cu in $(grep -l "site_group_kernels__locals__ends" -r ~/.cache/warp --include=*.cu 2>/dev/null); do
  dir=$(dirname "$cu")
  for bin in "$dir"/*.cubin; do
    [ -f "$bin" ] || continue
    echo "#### $(grep -o "__launch_bounds__([0-9, ]*)" "$cu" | head -1) $(grep -c "var_" "$cu") $dir" >> "$out/warp-group.sass"
    "$co" -sass "$bin" >> "$out/warp-group.sass" 2>&1
  done
done
: > "$out/hand.sass"
for bin in $(find ~/.cupy/kernel_cache -name "*.cubin" 2>/dev/null); do
  echo "#### $bin" >> "$out/hand.sass"
  "$co" -sass "$bin" >> "$out/hand.sass" 2>&1
done
wc -l "$out"/*.sass
