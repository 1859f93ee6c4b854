#!/usr/bin/env bash
# Incremental in-place build of line_odom_core._core and ._testing for development: scripts/dev_build.sh [NAME]
# NAME keeps a separate object directory (build/tmp_NAME) so parallel builds do not share objects.
set -euo pipefail
cd "$(dirname "$0")/.."
name="${1:-dev}"
exec .venv/bin/python setup.py -q build_ext --inplace --build-temp "build/tmp_${name}" --build-lib "build/lib_${name}"
