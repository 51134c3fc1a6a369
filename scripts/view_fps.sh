#!/bin/bash
# Frame rate of `nacre view` for one kind of edit, as docs/performance.md ("Viewer") measures it:
# runs of 21 and 81 frames of the same script (one event per frame), under xvfb-run; the rate is
# 60 frames over the difference of their wall times, so start-up and the first full frame cancel.
# Prints ms per frame, fps and the per-stage means of those 60 frames.
# usage: scripts/view_fps.sh SCENE.json|- SCRIPT [view options...]   (- : the built-in demo)
# e.g.   printf '0 voxel_res 64\n' > s.txt; for i in $(seq 1 90); do echo "$i orbit 1 0"; done >> s.txt
#        chrt -f 20 scripts/view_fps.sh - s.txt
set -e
nacre=${NACRE:-build/release/nacre}
scene=$1; script=$2; shift 2
args=()
[ "$scene" != "-" ] && args=("$scene")
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for f in 21 81; do
    awk -v F=$f '$1 < F' "$script" > "$tmp/s$f.txt"
    xvfb-run -a "$nacre" view "${args[@]}" --frames $f --script "$tmp/s$f.txt" "$@" | tail -1 > "$tmp/r$f.json"
done
python3 - "$tmp/r21.json" "$tmp/r81.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
ms = (b["seconds"] - a["seconds"]) / 60 * 1000
stages = {k[:-3]: round((b[k] - a[k]) / 60 / 1000, 2) for k in b if k.endswith("_us") and (b[k] - a[k]) / 60 > 300}
print(f"{ms:.1f} ms per frame, {1000 / ms:.1f} fps, stages (ms): {stages}")
PY
