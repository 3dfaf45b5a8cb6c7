#!/usr/bin/env bash
# Install OpenSubdiv (Debian/Ubuntu package libosd-dev) for the differential tests and benchmarks, quietly.
# Does nothing (exit 0) where it is already installed, where apt-get is unavailable, or where we are neither
# root nor able to use sudo without a password. Never fails its caller: every outcome exits 0.
# Set OSD_INSTALL_VERBOSE=1 to see apt's output.
if [ -f /usr/include/opensubdiv/far/topologyRefiner.h ]; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "install_osd.sh: no apt-get; skipping libosd-dev (the OpenSubdiv tests will skip)" >&2
    exit 0
fi
if [ "$(id -u)" = "0" ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1 && sudo -n true >/dev/null 2>&1; then
    SUDO="sudo -n"
else
    echo "install_osd.sh: not root and no password-less sudo; skipping libosd-dev" >&2
    exit 0
fi
if [ "${OSD_INSTALL_VERBOSE:-0}" = "1" ]; then log=/dev/stderr; else log=/dev/null; fi
export DEBIAN_FRONTEND=noninteractive
# update the package lists only when the package is not known yet
if ! apt-cache show libosd-dev >/dev/null 2>&1; then
    $SUDO apt-get update -qq >"$log" 2>&1 || true
fi
if $SUDO apt-get install -y -qq --no-install-recommends libosd-dev g++ >"$log" 2>&1; then
    echo "install_osd.sh: installed libosd-dev" >&2
else
    echo "install_osd.sh: apt-get install libosd-dev failed; the OpenSubdiv tests will skip" >&2
fi
exit 0
