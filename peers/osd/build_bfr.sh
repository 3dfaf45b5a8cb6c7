#!/usr/bin/env bash
# Build peers/osd/build/bfr_peer against the system's OpenSubdiv (Debian: libosd-dev, with Bfr: 3.5 or later).
# Usage: peers/osd/build_bfr.sh   (CXX and CXXFLAGS may be overridden; exit 1 when OpenSubdiv or Bfr is missing)
# bfr_peer.cpp includes osd_peer.cpp (its record files and mesh input), so it is built from both.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="$here/build"
CXX="${CXX:-g++}"
if [ ! -f /usr/include/opensubdiv/bfr/surface.h ]; then
    echo "build_bfr.sh: OpenSubdiv's Bfr headers not found (install libosd-dev 3.5+: peers/install_osd.sh)" >&2
    exit 1
fi
mkdir -p "$out"
# build into a temporary name and rename, so a concurrent or interrupted build never leaves a broken binary
tmp="$(mktemp "$out/.bfr_peer.XXXXXX")"
trap 'rm -f "$tmp"' EXIT
"$CXX" -std=c++14 -O2 ${CXXFLAGS:-} -Wall -Wextra -o "$tmp" "$here/bfr_peer.cpp" -losdCPU
chmod 755 "$tmp"
mv -f "$tmp" "$out/bfr_peer"
trap - EXIT
echo "$out/bfr_peer"
