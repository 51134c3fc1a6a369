#!/usr/bin/env bash
# limits.sh NACRE: settings and files that ask for more memory than the process may have end with
# exit 2 and one line, not with the kernel killing the process. Runs the command under
# `ulimit -v 4194304` (4 GiB of address space), which sanitizer builds cannot run under, so
# `make test` gives it the release build. Prints "N passed, M failed"; exit 1 on any failure.
set -u
nacre=${1:?usage: limits.sh path/to/nacre}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
passed=0
failed=0

# expect_refusal NAME WORDS ARGS...: exit status 2, one line on stderr containing WORDS.
expect_refusal() {
    local name=$1 words=$2
    shift 2
    local rc
    (ulimit -v 4194304 && exec "$nacre" "$@") >"$tmp/out" 2>"$tmp/err"
    rc=$?
    local lines
    lines=$(wc -l <"$tmp/err")
    if [ "$rc" -eq 2 ] && [ "$lines" -eq 1 ] && grep -q -- "$words" "$tmp/err"; then
        passed=$((passed + 1))
    else
        failed=$((failed + 1))
        echo "FAIL $name: exit $rc, $lines lines on stderr:" >&2
        head -c 2000 "$tmp/err" >&2
    fi
}

printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n' >"$tmp/tri.obj"
expect_refusal "voxelize --res 4096" "memory limit" voxelize "$tmp/tri.obj" --res 4096 -o "$tmp/v.nrrd"
expect_refusal "render --voxel-res 1024" "memory limit" render --method diffusion --voxel-res 1024 -o "$tmp/d.png"

{
    printf '{"render": {"width": 32, "height": 24}, "lights": ['
    for i in $(seq 0 49); do
        [ "$i" -gt 0 ] && printf ', '
        printf '{"type": "point", "position": [%d, 3, 0], "intensity": 1}' "$i"
    done
    printf '], "materials": {"m": {"type": "opaque"}},'
    printf ' "objects": [{"shape": {"type": "sphere"}, "material": "m"}]}\n'
} >"$tmp/lights50.json"
expect_refusal "50 point lights" "50 shadow maps" render "$tmp/lights50.json" -o "$tmp/l.png"

# A 17 KB EXR whose data window says 16384 x 16384: a real 16 x 16 image with the window's
# maximum corner rewritten, padded to 17 KB.
printf '{"render": {"width": 16, "height": 16}, "materials": {"m": {"type": "opaque"}},\n "objects": [{"shape": {"type": "sphere"}, "material": "m"}]}\n' >"$tmp/s.json"
"$nacre" render "$tmp/s.json" -o "$tmp/small.exr" >/dev/null 2>&1
off=$(grep -obUa 'dataWindow' "$tmp/small.exr" | head -1 | cut -d: -f1)
if [ -n "$off" ]; then
    # name + NUL, "box2i" + NUL, int32 size, then xmin ymin xmax ymax
    max=$((off + 11 + 6 + 4 + 8))
    printf '\xff\x3f\x00\x00\xff\x3f\x00\x00' | dd of="$tmp/small.exr" bs=1 seek="$max" conv=notrunc status=none
    truncate -s 17408 "$tmp/small.exr"
    expect_refusal "17 KB EXR saying 16384^2" "can hold" compare "$tmp/small.exr" "$tmp/small.exr"
else
    failed=$((failed + 1))
    echo "FAIL: could not write the EXR to corrupt" >&2
fi

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
