#!/usr/bin/env bash
# The Python package's tests, as on a fresh machine: a new virtual environment, the package built from
# this checkout by `pip install` (pip fetches maturin from PyPI for the build), numpy and pytest, the
# `trand` CLI (the tests compare the package with it), then pytest. Needs python3 (3.9 or later) with
# the venv module, cargo, and PyPI.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
python="${PYTHON:-python3}"
target="${CARGO_TARGET_DIR:-$root/target}"
venv="${TRAND_PY_VENV:-$target/py-venv}"
command -v "$python" >/dev/null || { echo "$python is required for the Python package's tests"; exit 1; }

rm -rf "$venv"
"$python" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet numpy pytest
"$venv/bin/python" -m pip install "$here"
(cd "$root" && cargo build --release -p trand-cli)
cd "$here"
TRAND_CLI="$target/release/trand" "$venv/bin/python" -m pytest -q tests "$@"
