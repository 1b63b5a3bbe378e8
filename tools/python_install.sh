#!/usr/bin/env bash
# Builds and installs the Python package (python/, PyO3 + maturin) into the repository's
# virtual environment python/.venv, with the tools its tests need (pytest, numpy, plyfile).
# The build is `pip install .` at the repository root: maturin compiles the binding crate in
# release mode into the shared target/ folder, so the release build of the dependencies that
# `cargo build --release` made is reused. Safe to rerun: the venv and its tools are kept, the
# package is rebuilt (cargo recompiles only what changed).
#
# Usage (from anywhere): bash tools/python_install.sh
# Then: python/.venv/bin/python -m pytest tests/python
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/python/.venv"

if [[ ! -x "$venv/bin/python" ]]; then
    python3 -m venv "$venv"
fi
"$venv/bin/pip" install --quiet --disable-pip-version-check -r "$root/python/requirements.txt"
# Without build isolation pip uses the pinned maturin above instead of downloading another.
start=$(date +%s)
PATH="$venv/bin:$PATH" "$venv/bin/pip" install --quiet --disable-pip-version-check \
    --no-build-isolation --force-reinstall --no-deps "$root"
echo "python_install: built and installed the stablesurf package in $(( $(date +%s) - start )) s" >&2
