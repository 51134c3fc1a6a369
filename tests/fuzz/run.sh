#!/usr/bin/env bash
# Runs the libFuzzer targets of tests/fuzz one after another, each for a bounded time, and fails
# if any of them finds a crash, a leak, a timeout or an allocation over the limits.
#
#   tests/fuzz/run.sh BUILD_DIR SECONDS [TARGET...]      (TARGET: scene mesh image nrrd depth_map)
#
# Each target starts from its seed corpus (tests/fuzz/corpus/<target>, read only) and from the
# inputs it found in earlier runs (BUILD_DIR/fuzz-work/<target>/corpus, where new ones go), so
# coverage grows from run to run without touching the source tree. Crash inputs land in
# BUILD_DIR/fuzz-work/<target>/artifacts/, the output in BUILD_DIR/fuzz-work/<target>/log.
# Extra libFuzzer flags can come from NACRE_FUZZ_FLAGS (e.g. "-jobs=2 -workers=2"), another
# work folder from NACRE_FUZZ_WORK. NACRE_FUZZ_FIXED=1 runs each target for a fixed number of
# inputs (runs_for below) instead of until SECONDS, which then only bounds the time: with a
# fixed -seed and an empty work folder, every machine then tries nearly the same inputs (threads
# make coverage, and so the mutations kept, differ slightly from run to run).
set -uo pipefail

if [ $# -lt 2 ]; then
    echo "usage: $0 BUILD_DIR SECONDS [TARGET...]" >&2
    exit 2
fi
build=$(cd "$1" && pwd) || exit 2
seconds=$2
shift 2
src=$(cd "$(dirname "$0")" && pwd)
targets=("$@")
[ ${#targets[@]} -eq 0 ] && targets=(scene mesh image nrrd depth_map)

# Longest generated input per target: a few times the largest seed, so mutations can grow a
# file but no input gets big enough to make one run slow.
max_len() {
    case $1 in
    scene) echo 8192 ;;
    mesh) echo 4096 ;;
    *) echo 2048 ;;
    esac
}

# Inputs per target under NACRE_FUZZ_FIXED: about 20 s each on an idle 2-core machine (the mesh
# target goes through assimp, two orders of magnitude slower per input than the others).
runs_for() {
    case $1 in
    mesh) echo 4000 ;;
    *) echo 100000 ;;
    esac
}

work=${NACRE_FUZZ_WORK:-$build/fuzz-work}
mkdir -p "$work/tmp"
export NACRE_FUZZ_TMP=$work/tmp
# UBSan is built with -fno-sanitize-recover, so a report aborts; the stack says where.
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1}

failed=()
for t in "${targets[@]}"; do
    exe=$build/tests/fuzz/fuzz_$t
    if [ ! -x "$exe" ]; then
        echo "fuzz: $exe missing (build it with: make build-fuzz)" >&2
        failed+=("$t")
        continue
    fi
    mkdir -p "$work/$t/corpus" "$work/$t/artifacts"
    dict=()
    [ -f "$src/$t.dict" ] && dict=(-dict="$src/$t.dict")
    runs=()
    [ -n "${NACRE_FUZZ_FIXED:-}" ] && runs=(-runs="$(runs_for "$t")")
    start=$(date +%s)
    # rss_limit_mb / malloc_limit_mb: no input may make the library hold or ask for more than
    # this (the loaders' size checks are what is being tested); timeout: one input, seconds.
    # shellcheck disable=SC2086
    "$exe" -max_total_time="$seconds" -max_len="$(max_len "$t")" -timeout=10 \
        -rss_limit_mb=2048 -malloc_limit_mb=1024 -print_final_stats=1 \
        -artifact_prefix="$work/$t/artifacts/" "${dict[@]}" "${runs[@]}" ${NACRE_FUZZ_FLAGS:-} \
        "$work/$t/corpus" "$src/corpus/$t" >"$work/$t/log" 2>&1
    rc=$?
    stats=$(grep -E '^stat::number_of_executed_units|^stat::new_units_added' "$work/$t/log" |
        sed 's/^stat:://' | tr '\n' ' ')
    if [ $rc -ne 0 ]; then
        echo "fuzz: $t FAILED (exit $rc after $(($(date +%s) - start)) s); log: $work/$t/log"
        grep -E '^==[0-9]+==ERROR|SUMMARY|FUZZ_REQUIRE|runtime error|Test unit written' "$work/$t/log" | head -20
        failed+=("$t")
    else
        echo "fuzz: $t ok in $(($(date +%s) - start)) s: $stats"
    fi
done
rm -rf "$work/tmp"

echo "fuzz: $((${#targets[@]} - ${#failed[@]})) passed, ${#failed[@]} failed"
if [ ${#failed[@]} -ne 0 ]; then
    echo "fuzz: FAILED: ${failed[*]} (inputs in $work/<target>/artifacts/; see tests/fuzz/README.md)" >&2
    exit 1
fi
