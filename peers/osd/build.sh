#!/usr/bin/env bash
# Build one of the C++ peers against the system's OpenSubdiv (Debian: libosd-dev) into peers/osd/build/.
# Usage: peers/osd/build.sh [osd_peer|bfr_peer]   (default osd_peer; CXX and CXXFLAGS may be overridden;
# exit 1 when OpenSubdiv, or for bfr_peer its Bfr headers (3.5 or later), are missing).
# bfr_peer.cpp includes osd_peer.cpp (its record files and mesh input), so it is built from both.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="$here/build"
CXX="${CXX:-g++}"
program="${1:-osd_peer}"
case "$program" in
    osd_peer) header=/usr/include/opensubdiv/far/topologyRefiner.h; what="OpenSubdiv headers" ;;
    bfr_peer) header=/usr/include/opensubdiv/bfr/surface.h; what="OpenSubdiv's Bfr headers (libosd-dev 3.5+)" ;;
    *) echo "build.sh: unknown program '$program' (osd_peer or bfr_peer)" >&2; exit 2 ;;
esac
if [ ! -f "$header" ]; then
    echo "build.sh: $what not found (install libosd-dev: peers/install_osd.sh)" >&2
    exit 1
fi
mkdir -p "$out"
# build into a temporary name and rename, so a concurrent or interrupted build never leaves a broken binary
tmp="$(mktemp "$out/.$program.XXXXXX")"
trap 'rm -f "$tmp"' EXIT
"$CXX" -std=c++14 -O2 ${CXXFLAGS:-} -Wall -Wextra -o "$tmp" "$here/$program.cpp" -losdCPU
chmod 755 "$tmp"
mv -f "$tmp" "$out/$program"
trap - EXIT
echo "$out/$program"
