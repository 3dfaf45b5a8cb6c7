#!/usr/bin/env bash
# Build peers/osd/build/osd_peer against the system's OpenSubdiv (Debian: libosd-dev).
# Usage: peers/osd/build.sh   (CXX and CXXFLAGS may be overridden; exit 1 when OpenSubdiv is missing)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="$here/build"
CXX="${CXX:-g++}"
if [ ! -f /usr/include/opensubdiv/far/topologyRefiner.h ]; then
    echo "build.sh: OpenSubdiv headers not found (install libosd-dev: peers/install_osd.sh)" >&2
    exit 1
fi
mkdir -p "$out"
# build into a temporary name and rename, so a concurrent or interrupted build never leaves a broken binary
tmp="$(mktemp "$out/.osd_peer.XXXXXX")"
trap 'rm -f "$tmp"' EXIT
"$CXX" -std=c++14 -O2 ${CXXFLAGS:-} -Wall -Wextra -o "$tmp" "$here/osd_peer.cpp" -losdCPU
chmod 755 "$tmp"
mv -f "$tmp" "$out/osd_peer"
trap - EXIT
echo "$out/osd_peer"
