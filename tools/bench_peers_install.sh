#!/usr/bin/env bash
# Installs what tools/bench_peers needs, on top of tools/install-validators.sh (which creates
# tools/validate/.venv with pymeshlab): the Debian library Open3D loads (libusb-1.0), Open3D 0.20
# from PyPI (a 400 MB wheel, installed without its optional dependencies), plotly and dash (which
# `import open3d` needs) and scipy. Safe to rerun: skipped when everything imports.
# Measured here: about 1 minute with a cold pip cache (download 9 s, install 20 s, dash/plotly 35 s).
#
# Usage (from anywhere): bash tools/bench_peers_install.sh
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
py="$here/validate/.venv/bin/python"

bash "$here/install-validators.sh"

if ! dpkg-query -W -f='${Status}' libusb-1.0-0 2>/dev/null | grep -q "install ok installed"; then
    echo "bench_peers_install: installing Debian package libusb-1.0-0 (Open3D links it)" >&2
    sudo_cmd=()
    [[ $(id -u) -ne 0 ]] && sudo_cmd=(sudo)
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends libusb-1.0-0
fi

if ! "$py" -c "import open3d, pymeshlab, scipy" 2>/dev/null; then
    echo "bench_peers_install: installing open3d, plotly, dash, scipy into $here/validate/.venv" >&2
    "$py" -m pip install --quiet --disable-pip-version-check -r "$here/bench_peers_requirements.txt"
    "$py" -m pip install --quiet --disable-pip-version-check --no-deps open3d==0.20.0
fi
"$py" -c "
import sys
from importlib.metadata import version
print('bench_peers_install:', ', '.join(f'{p} {version(p)}' for p in ('open3d', 'pymeshlab', 'scipy', 'numpy')), file=sys.stderr)
"
