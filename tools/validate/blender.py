"""Imports stablesurf's mesh files into Blender (bpy, Blender as a Python module) and prints
what Blender made of each, one JSON line per file.

Usage: blender.py FILE...   (.glb, .gltf or .ply)

Each file is imported into an empty scene with Blender's own importers (glTF: io_scene_gltf2;
PLY: the built-in `wm.ply_import` with its default axes, +Z up). Printed per file:

- `objects`: the mesh objects the import made, and for the first one
- `vertices`, `faces`: Blender's counts (glTF splits no vertex: stablesurf writes one primitive);
- `min`, `max`, `dimensions`: the world-space bounding box of its vertices, in metres as Blender
  shows them (so a millimetre scan exported with `--units mm` must come out in centimetres);
- `smooth`: whether every face is shaded smooth or carries custom split normals (the file's
  normals kept);
- `colour`: the name of the colour attribute, if any, and `colour_mean`, the mean of its sRGB
  values over the vertices (0–1), so a test can compare them with the scan's colours.

Exits non-zero when a file cannot be imported or makes no mesh.
"""

import json
import os
import sys
from pathlib import Path

import bpy


def import_file(path: Path) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    suffix = path.suffix.lower()
    if suffix in (".glb", ".gltf"):
        result = bpy.ops.import_scene.gltf(filepath=str(path))
    elif suffix == ".ply":
        result = bpy.ops.wm.ply_import(filepath=str(path))
    else:
        raise SystemExit(f"{path}: not a .glb, .gltf or .ply file")
    if "FINISHED" not in result:
        raise SystemExit(f"{path}: Blender's importer returned {result}")


def describe(path: Path) -> dict:
    import_file(path)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    if not meshes:
        raise SystemExit(f"{path}: the import made no mesh object")
    obj = meshes[0]
    mesh = obj.data
    world = [obj.matrix_world @ v.co for v in mesh.vertices]
    lo = [min(v[a] for v in world) for a in range(3)]
    hi = [max(v[a] for v in world) for a in range(3)]
    custom_normals = "custom_normal" in mesh.attributes or getattr(mesh, "has_custom_normals", False)
    smooth = custom_normals or all(p.use_smooth for p in mesh.polygons)
    out = {
        "file": str(path),
        "objects": len(meshes),
        "vertices": len(mesh.vertices),
        "faces": len(mesh.polygons),
        "min": lo,
        "max": hi,
        "dimensions": [hi[a] - lo[a] for a in range(3)],
        "smooth": bool(smooth),
        "colour": None,
        "colour_mean": None,
    }
    if mesh.color_attributes:
        attribute = mesh.color_attributes[0]
        values = [c.color_srgb for c in attribute.data]
        out["colour"] = attribute.name
        out["colour_mean"] = [sum(v[a] for v in values) / len(values) for a in range(3)]
    return out


def main() -> None:
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    # Blender's importers print progress on stdout: send it to stderr, keep stdout for JSON.
    out = os.fdopen(os.dup(1), "w")
    sys.stdout.flush()
    os.dup2(2, 1)
    for name in sys.argv[1:]:
        line = json.dumps(describe(Path(name)))
        out.write(line + "\n")
        out.flush()


if __name__ == "__main__":
    main()
