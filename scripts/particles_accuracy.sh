#!/bin/sh
# The particle passes (billboards, sprites) and the density grid they splat into (--particles
# voxel, drawn by the froxel and the ray-marched volumetrics) against the path tracer on
# examples/particles.json at 320x240 (docs/accuracy.md, "Particles"). Needs the release build (build/release). Writes its
# images to ${OUT:-/tmp/nacre_particles}. The two path-traced references take minutes;
# KEEP_REFS=1 reuses those already in OUT.
set -e
ROOT=$(cd "$(dirname "$0")/.." && pwd)
NACRE="$ROOT/build/release/nacre"
OUT=${OUT:-/tmp/nacre_particles}
SPP=${SPP:-512}
mkdir -p "$OUT"
cc -O2 -I "$ROOT/include" "$ROOT/scripts/masked_compare.c" -o "$OUT/masked_compare" \
    "$ROOT/build/release/libnacre.so" -Wl,-rpath,"$ROOT/build/release" -lm
# The frame without particles: the scene with its "particles" section removed.
python3 -c 'import json, sys; d = json.load(open(sys.argv[1])); del d["particles"]; json.dump(d, open(sys.argv[2], "w"))' \
    "$ROOT/examples/particles.json" "$OUT/noparticles.json"
"$NACRE" render "$OUT/noparticles.json" --method phong --size 320x240 -o "$OUT/bg.exr"
for m in billboards sprites; do
    "$NACRE" render "$ROOT/examples/particles.json" --method phong --particles $m --size 320x240 -o "$OUT/$m.exr"
done
for v in froxel raymarch; do
    "$NACRE" render "$ROOT/examples/particles.json" --method phong --particles voxel --volumetrics $v \
        --size 320x240 -o "$OUT/voxel_$v.exr"
done
[ -f "$OUT/ref.exr" ] && [ -n "${KEEP_REFS:-}" ] ||
    "$NACRE" render "$ROOT/examples/particles.json" --method pathtrace --spp "$SPP" --seed 3 --size 320x240 -o "$OUT/ref.exr"
[ -f "$OUT/ref_single.exr" ] && [ -n "${KEEP_REFS:-}" ] ||
    "$NACRE" render "$ROOT/examples/particles.json" --method pathtrace --spp "$SPP" --seed 3 --max-scatter 1 \
        --size 320x240 -o "$OUT/ref_single.exr"
for ref in ref ref_single; do
    for m in billboards sprites voxel_froxel voxel_raymarch; do
        printf '%-14s vs %-10s ' "$m" "$ref"
        "$OUT/masked_compare" "$OUT/$m.exr" "$OUT/$ref.exr" "$OUT/bg.exr" "$OUT/billboards.exr" "$OUT/sprites.exr"
    done
done
