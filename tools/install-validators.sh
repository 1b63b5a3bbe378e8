#!/usr/bin/env bash
# Installs the external validators that tests/all/export.rs runs on stablesurf's output files:
#   - the Khronos glTF-Validator (npm package gltf-validator) into tools/validate/node_modules,
#   - plyfile, pymeshlab (MeshLab) and the OpenEXR Python bindings into tools/validate/.venv,
#     with laspy and lazrs, which write the LAS and LAZ files tests/all/import.rs reads, and
#     pye57 (libE57Format), which writes the E57 files it reads,
#   - Blender 5.0 as a Python module (bpy) into tools/validate/.venv-blender, its own
#     environment because it pins its own numpy,
#   - the Debian libraries pymeshlab and Blender load (OpenGL, X11, fontconfig, GLib).
# Safe to rerun: each step is skipped when already done. Needs node/npm and python3 (>= 3.9);
# the apt step needs root (or sudo) and is skipped when the libraries are already present.
#
# Usage (from anywhere): bash tools/install-validators.sh
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
validate="$here/validate"

# 1. Debian libraries pymeshlab links against (found with ldd on its bundled .so files).
debian_libs=(libgl1 libopengl0 libglx0 libx11-6 libxau6 libxdmcp6 libxcb1 libfontconfig1 libfreetype6 libglib2.0-0 libpng16-16 libbsd0 libgomp1
             libxrender1 libxfixes3 libxi6 libxkbcommon0 libxext6 libsm6 libice6 libuuid1)
missing=()
for pkg in "${debian_libs[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
    echo "install-validators: installing Debian packages: ${missing[*]}" >&2
    sudo_cmd=()
    [[ $(id -u) -ne 0 ]] && sudo_cmd=(sudo)
    "${sudo_cmd[@]}" apt-get update -qq
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# 2. Python validators in a repo-local virtual environment.
if [[ ! -x "$validate/.venv/bin/python" ]]; then
    python3 -m venv "$validate/.venv"
fi
if ! "$validate/.venv/bin/python" -c "import plyfile, pymeshlab, OpenEXR, numpy, laspy, lazrs, pye57" 2>/dev/null; then
    echo "install-validators: installing Python validators into $validate/.venv" >&2
    "$validate/.venv/bin/pip" install --quiet --disable-pip-version-check -r "$validate/requirements.txt"
fi
"$validate/.venv/bin/python" -c "
import sys
from importlib.metadata import version
print('install-validators:', ', '.join(f'{p} {version(p)}' for p in ('plyfile', 'pymeshlab', 'OpenEXR', 'numpy', 'laspy', 'lazrs', 'pye57')), file=sys.stderr)
"

# 3. Blender as a Python module, for the import checks of tools/validate/blender.py.
if [[ ! -x "$validate/.venv-blender/bin/python" ]]; then
    python3 -m venv "$validate/.venv-blender"
fi
if ! "$validate/.venv-blender/bin/python" -c "import bpy" 2>/dev/null; then
    echo "install-validators: installing Blender (bpy) into $validate/.venv-blender" >&2
    "$validate/.venv-blender/bin/pip" install --quiet --disable-pip-version-check -r "$validate/requirements-blender.txt"
fi
"$validate/.venv-blender/bin/python" -c "import sys, bpy; print('install-validators: Blender', bpy.app.version_string, file=sys.stderr)"

# 4. The Khronos glTF-Validator from npm, pinned by package-lock.json.
if [[ ! -f "$validate/node_modules/gltf-validator/package.json" ]]; then
    echo "install-validators: installing gltf-validator into $validate/node_modules" >&2
    (cd "$validate" && npm ci --no-audit --no-fund --loglevel=error)
fi
node -e "console.error('install-validators: gltf-validator', require('$validate/node_modules/gltf-validator').version())"
echo "install-validators: done" >&2
