#!/usr/bin/env bash
# The one set-up path of line_odom (`make setup`; `make demo` and `make test` run it first).
#
#   1. CPython 3.11 (the ROS 2 Jazzy wheels are built for 3.11); PYTHON=/path/to/python3.11 to choose
#   2. system packages the build needs (g++, cmake, Eigen headers, Python headers, venv) - apt-get when
#      missing - and .venv in the repository root
#   3. pinned Python dependencies: requirements/dev.txt (and no-deps.txt) under the constraints requirements/lock.txt
#   4. tf2_msgs built into the venv when `import tf2_msgs.msg` fails (scripts/build_tf2_msgs.sh)
#   5. line_odom itself, editable (pip install -e .), with the engine extension built in place
#
# Every step is skipped when its result is present and its inputs (hashed into .venv/.setup/) are
# unchanged, so re-running takes seconds and changes nothing. After it, .venv/bin/python runs
# everything; no environment variables are needed.
set -euo pipefail

ROOT="$(cd "$(dirname "$0")/.." && pwd)"
cd "$ROOT"
SECONDS=0
VENV="$ROOT/.venv"
PY="$VENV/bin/python"
STAMPS="$VENV/.setup"
REQ="$ROOT/requirements"

say() { echo "setup: [${SECONDS}s] $*"; }
die() { echo "setup: ERROR: $*" >&2; exit 1; }

# pip on some machines is configured with local indexes that print one warning per package looked up;
# drop exactly those lines, keep everything else (and pip's exit status).
pip_quiet() {
    "$PY" -m pip "$@" --disable-pip-version-check -q 2>&1 \
        | { grep -v -E "^WARNING: Location '.*' is ignored: it is neither a file nor a directory\.$" || true; }
    return "${PIPESTATUS[0]}"
}

# hash of the given files' contents and names, plus the interpreter version
fingerprint() {
    { "$PY" -c 'import sys; print(sys.version)'; for f in "$@"; do echo "== $f"; cat "$f"; done; } \
        | sha256sum | cut -d' ' -f1
}
stamp_ok() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
stamp_set() { mkdir -p "$STAMPS"; echo "$2" > "$STAMPS/$1"; }

# one set-up at a time per checkout (make test in two terminals, CI)
mkdir -p "$ROOT/build"
if command -v flock >/dev/null 2>&1; then
    exec 9>"$ROOT/build/.setup.lock"
    flock 9
fi

# ---- 1. the interpreter: CPython 3.11 (the ROS 2 Jazzy wheels are cp311) -------------------------
is_py311() { "$1" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; }
base=""
if [ ! -x "$PY" ]; then
    for cand in "${PYTHON:-}" python3 python3.11; do
        [ -n "$cand" ] && command -v "$cand" >/dev/null 2>&1 && is_py311 "$cand" && { base="$(command -v "$cand")"; break; }
    done
    [ -n "$base" ] || die "CPython 3.11 not found (python3 is $(python3 --version 2>&1 || echo missing)). The ROS 2 Jazzy wheels need 3.11: install it (apt-get install python3.11 python3.11-venv python3.11-dev, or pyenv) or set PYTHON=/path/to/python3.11."
else
    is_py311 "$PY" || die ".venv does not run CPython 3.11; remove it (rm -rf .venv) and re-run."
fi
interp="${base:-$PY}"

# ---- 2. system packages --------------------------------------------------------------------------
eigen_found() {
    local d
    for d in "${EIGEN3_INCLUDE_DIR:-}" /usr/include/eigen3 /usr/local/include/eigen3; do
        [ -n "$d" ] && [ -f "$d/Eigen/Core" ] && return 0
    done
    return 1
}
python_headers_found() {
    "$interp" -c 'import os, sys, sysconfig; sys.exit(not os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' 2>/dev/null
}
missing=()
command -v g++ >/dev/null 2>&1 || missing+=(g++)
command -v cmake >/dev/null 2>&1 || missing+=(cmake)
eigen_found || missing+=(libeigen3-dev)
python_headers_found || missing+=(python3.11-dev)
if [ -n "$base" ] && ! "$base" -c 'import ensurepip' >/dev/null 2>&1; then missing+=(python3.11-venv); fi
if [ "${#missing[@]}" -gt 0 ]; then
    say "installing system packages: ${missing[*]}"
    if ! command -v apt-get >/dev/null 2>&1; then
        die "missing ${missing[*]} and apt-get is not available: install g++, cmake, the Eigen 3 headers (or set EIGEN3_INCLUDE_DIR to the directory holding Eigen/Core) and Python 3.11's headers and venv module with your package manager, then re-run."
    fi
    if [ "$(id -u)" -eq 0 ]; then
        SUDO=()
    elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        SUDO=(sudo -n)
    else
        die "missing ${missing[*]}; installing needs root. Run: sudo apt-get update && sudo apt-get install -y ${missing[*]}  - then re-run."
    fi
    export DEBIAN_FRONTEND=noninteractive
    "${SUDO[@]}" apt-get update -q </dev/null >/dev/null \
        || die "apt-get update failed; install ${missing[*]} yourself, then re-run."
    "${SUDO[@]}" apt-get install -y -q --no-install-recommends "${missing[@]}" </dev/null >/dev/null \
        || die "apt-get install ${missing[*]} failed; install them yourself, then re-run."
    eigen_found || die "Eigen headers still not found after installing libeigen3-dev."
    python_headers_found || die "Python.h of $interp still not found after installing python3.11-dev."
fi

# ---- the virtual environment ---------------------------------------------------------------------
if [ -n "$base" ]; then
    say "creating .venv with $base ($("$base" --version 2>&1))"
    "$base" -m venv "$VENV" || die "could not create .venv (on Debian/Ubuntu: apt-get install python3.11-venv)."
fi

# ---- 3. pinned Python dependencies ---------------------------------------------------------------
deps_fp="$(fingerprint "$REQ/base.txt" "$REQ/dev.txt" "$REQ/no-deps.txt" "$REQ/lock.txt")"
if ! stamp_ok deps "$deps_fp"; then
    say "installing pinned Python dependencies (requirements/dev.txt, constraints requirements/lock.txt)"
    pip_quiet install "$(grep -E '^pip==' "$REQ/lock.txt")" || die "could not install pip"
    pip_quiet install -r "$REQ/dev.txt" -c "$REQ/lock.txt" || die "pip install -r requirements/dev.txt failed"
    # (no-deps.txt says why these come without their declared dependencies)
    pip_quiet install --no-deps -r "$REQ/no-deps.txt" -c "$REQ/lock.txt" || die "pip install -r requirements/no-deps.txt failed"
    stamp_set deps "$deps_fp"
fi

# ---- 4. tf2_msgs ---------------------------------------------------------------------------------
if ! (cd / && "$PY" -c 'import tf2_msgs.msg' >/dev/null 2>&1); then
    say "building tf2_msgs into .venv (not shipped as a wheel)"
    pip_quiet install -r "$REQ/tf2-build.txt" -c "$REQ/lock.txt" || die "pip install -r requirements/tf2-build.txt failed"
    bash "$ROOT/scripts/build_tf2_msgs.sh" "$VENV"
fi

# ---- 5. line_odom, editable, engine built in place -----------------------------------------------
pkg_fp="$(fingerprint setup.py setup.cfg package.xml)"
mapfile -t engine_headers < <(find line_odom_core/cpp -type f \( -name '*.hpp' -o -name '*.h' \) | LC_ALL=C sort)
mapfile -t engine_sources < <(find line_odom_core/cpp -type f -name '*.cpp' | LC_ALL=C sort)
headers_fp="$(fingerprint setup.py "${engine_headers[@]}")"
engine_fp="$(fingerprint setup.py "${engine_headers[@]}" "${engine_sources[@]}")"
ext_present() { compgen -G "line_odom_core/_core.cpython-*.so" >/dev/null && compgen -G "line_odom_core/_testing.cpython-*.so" >/dev/null; }
if ! stamp_ok package "$pkg_fp" || ! (cd / && "$PY" -c 'import line_odom' >/dev/null 2>&1); then
    say "installing line_odom (editable) and building the C++ engine (a few minutes)"
    pip_quiet install --no-build-isolation --no-deps -e "$ROOT" || die "pip install -e . failed"
    stamp_set package "$pkg_fp"
    stamp_set headers "$headers_fp"
    stamp_set engine "$engine_fp"
elif ! stamp_ok engine "$engine_fp" || ! ext_present; then
    # The fingerprints say something changed, so --force past distutils' whole-extension check (whole-second
    # mtimes); the objects older than their .cpp or than any engine header are recompiled (build_support.py).
    headers_note=""
    stamp_ok headers "$headers_fp" || headers_note=" (headers changed: every object)"
    say "engine sources changed: rebuilding line_odom_core._core and ._testing${headers_note}"
    "$PY" setup.py -q build_ext --inplace --force --build-temp build/tmp_setup --build-lib build/lib_setup \
        || die "building line_odom_core._core and ._testing failed"
    stamp_set headers "$headers_fp"
    stamp_set engine "$engine_fp"
fi

(cd / && "$PY" -c 'import line_odom, line_odom_core, rclpy, tf2_msgs.msg') \
    || die "final check failed: .venv/bin/python cannot import line_odom, line_odom_core, rclpy and tf2_msgs"
say "ready: $PY"
