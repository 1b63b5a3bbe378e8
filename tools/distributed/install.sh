#!/usr/bin/env bash
# Creates tools/distributed/.venv with the pinned Dask (requirements.txt) for fit_dask.py.
# Safe to rerun: skipped when dask.distributed already imports there.
#
# Usage (from anywhere): bash tools/distributed/install.sh
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv"
if [[ ! -x "$venv/bin/python" ]]; then
    python3 -m venv "$venv"
fi
if ! "$venv/bin/python" -c "import dask.distributed" 2>/dev/null; then
    echo "distributed/install.sh: installing $(grep -v '^#' "$here/requirements.txt" | xargs) into $venv" >&2
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$here/requirements.txt"
fi
"$venv/bin/python" -c "import dask, distributed; print('dask', dask.__version__, 'distributed', distributed.__version__)"
