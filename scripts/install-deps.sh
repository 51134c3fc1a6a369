#!/usr/bin/env bash
# Installs the Debian 12 packages nacre needs to build and test. Idempotent: installs only what
# is missing; through sudo when not root. If it cannot install, it names the packages.
set -euo pipefail

packages=(build-essential cmake pkg-config libcjson-dev libspng-dev libopenexr-dev libassimp-dev libstb-dev zlib1g-dev libembree-dev)
# The fuzz targets (tests/fuzz): clang with libFuzzer (libclang-rt-dev), clang's OpenMP runtime
# (libomp-dev), llvm-symbolizer for readable sanitizer stacks (llvm). The unversioned packages
# follow Debian's default clang, so compiler and runtimes always match.
packages+=(clang libclang-rt-dev libomp-dev llvm)
# `nacre view` (tools/view): SDL2 for the window, input and frame texture, Dear ImGui 1.86 with
# its SDL2 + SDL_Renderer backends for the panel, and Xvfb (with xauth, which xvfb-run needs) so
# the viewer's test runs without a display. Without SDL2 the build leaves the viewer out.
packages+=(libsdl2-dev libimgui-dev libgl-dev xvfb xauth)
# OpenVDB volumes (.vdb): libopenvdb-dev 10, whose headers also include Boost's (header-only
# parts, libboost-dev). Without them the build leaves .vdb reading out. python3-openvdb is not
# needed: the test files are committed (scripts/make_vdb_tests.py regenerates them).
packages+=(libopenvdb-dev libboost-dev)

missing=()
for p in "${packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}"
if [ "$(id -u)" -eq 0 ]; then
    sudo_cmd=()
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    sudo_cmd=(sudo -n)
else
    echo "install-deps: need root to install these Debian packages; run as root:" >&2
    echo "  apt-get install -y ${missing[*]}" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
if ! "${sudo_cmd[@]}" apt-get install -y -q "${missing[@]}"; then
    # A fresh machine may have no package lists yet.
    "${sudo_cmd[@]}" apt-get update -q || true
    "${sudo_cmd[@]}" apt-get install -y -q "${missing[@]}" || {
        echo "install-deps: could not install: ${missing[*]}" >&2
        exit 1
    }
fi
