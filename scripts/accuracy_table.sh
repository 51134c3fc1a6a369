#!/usr/bin/env bash
# Make docs/accuracy.md's table of the diffusion method against the path tracer: for each scene,
# a path-traced reference, then diffusion at each voxel resolution, compared over the object's
# pixels by `nacre compare --json` (lit_ratio, dark_ratio, lit_rel_err_median/_p90). Scenes
# other than the two accuracy examples are rendered with a black environment and without their
# ground, so that the lit pixels are the translucent objects alone.
#
#   scripts/accuracy_table.sh [--nacre PATH] [--size WxH] [--ref-seconds S] [--res "16 32 64 128"]
#                             [--out DIR] [--reuse-ref] [--args "ARGS"] [SCENE.json ...]
#
# --args passes more options to the diffusion renders (e.g. "--single-scattering on"); their
# images are then named diffusion<res><tag>.exr, tag the options without spaces and dashes.
# --reuse-ref keeps a reference already in DIR (same scene and size: compare before/after a change
# against one reference).
#
# Prints one Markdown row per scene and resolution. tests/unit/test_accuracy.c asserts the
# default resolution's row of the first two scenes at a coarse size and sample count.
set -euo pipefail

nacre=build/release/nacre
size=128x128
ref_seconds=60
res="16 32 64 128"
out=${TMPDIR:-/tmp}/nacre-accuracy
reuse=0
extra=""
scenes=()
while [ $# -gt 0 ]; do
    case "$1" in
        --nacre) nacre=$2; shift 2 ;;
        --size) size=$2; shift 2 ;;
        --ref-seconds) ref_seconds=$2; shift 2 ;;
        --res) res=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        --reuse-ref) reuse=1; shift ;;
        --args) extra=$2; shift 2 ;;
        -h|--help) sed -n 2,19p "$0"; exit 0 ;;
        -*) echo "accuracy_table: unknown option $1" >&2; exit 2 ;;
        *) scenes+=("$1"); shift ;;
    esac
done
[ ${#scenes[@]} -gt 0 ] || scenes=(examples/accuracy_sphere.json examples/accuracy_checker.json
                                   examples/jade_torus.json examples/deformers.json)
[ -x "$nacre" ] || { echo "accuracy_table: $nacre not found (make build)" >&2; exit 2; }
mkdir -p "$out"

echo "| scene | voxels | mean ratio R, G, B | darkest quarter R, G, B | rel. error median, p90 |"
echo "|---|---|---|---|---|"
for scene in "${scenes[@]}"; do
    name=$(basename "$scene" .json)
    variant="$out/$name.json"
    python3 - "$scene" "$variant" <<'EOF'
import json, os, sys
src = sys.argv[1]
base = os.path.dirname(os.path.abspath(src))
def absolute(v):
    # Files the scene names (meshes, maps, volumes) resolve against the original's folder.
    if isinstance(v, dict):
        return {k: absolute(x) for k, x in v.items()}
    if isinstance(v, list):
        return [absolute(x) for x in v]
    if isinstance(v, str) and not os.path.isabs(v) and os.path.isfile(os.path.join(base, v)):
        return os.path.join(base, v)
    return v
d = absolute(json.load(open(src)))
d["environment"] = [0, 0, 0]
d["objects"] = [o for o in d["objects"] if o.get("name") != "ground"]
d.get("render", {}).pop("method", None)
json.dump(d, open(sys.argv[2], "w"), indent=1)
EOF
    ref="$out/$name.ref.exr"
    if [ $reuse = 0 ] || [ ! -f "$ref" ]; then
        "$nacre" render "$variant" --method pathtrace --size "$size" --spp 1000000 --time-limit "$ref_seconds" \
            --exr-float -o "$ref" >/dev/null
    fi
    for r in $res; do
        tag=$(echo "$extra" | tr -d ' -')
        img="$out/$name.diffusion$r$tag.exr"
        # shellcheck disable=SC2086
        "$nacre" render "$variant" --method diffusion --size "$size" --voxel-res "$r" $extra --exr-float -o "$img" >/dev/null
        "$nacre" compare "$img" "$ref" --json | python3 -c '
import json, sys
m = json.load(sys.stdin)
r, d = m["lit_ratio"], m["dark_ratio"]
print("| %s | %s³ | %.3f, %.3f, %.3f | %.2f, %.2f, %.2f | %.1f%%, %.1f%% |" % (sys.argv[1], sys.argv[2],
      r[0], r[1], r[2], d[0], d[1], d[2], 100 * m["lit_rel_err_median"], 100 * m["lit_rel_err_p90"]))
' "$name" "$r"
    done
done
