"""Checks a stablesurf volume.vdb in Blender (bpy) and with the OpenVDB module Blender ships.

Usage: tools/validate/.venv-blender/bin/python tools/validate/vdb_blender.py
           VOLUME.vdb MESH.ply VOLUME.json [--up y|z] [--metres-per-unit F] [--glb MESH.glb]

VOLUME.json is the npy sidecar of the same run (volume.npy beside it): it gives the grid the vdb
must hold (voxel size, origin of voxel (0, 0, 0), shape, in input units). --up and
--metres-per-unit are the run's --up and the size of its --units in metres (1 without).

Blender: the file must import as a Volume (bpy.ops.object.volume_import) with exactly one grid,
a float grid named `surface`, whose index-to-object matrix (grid.matrix_object) is the uniform
scale and translation the sidecar implies in Blender's frame (input (x, y, z) becomes
(x, -z, y) with --up y, as Blender's glTF importer turns a glb; unchanged with --up z; scaled to
metres). A Volume to Mesh modifier (threshold 0, the grid's own resolution) turns it into a
mesh, which is compared with MESH.ply imported by Blender's PLY importer and put in the same
frame: distances from each mesh's vertices to the other mesh's surface (BVH trees), in voxels.
With --glb, the run's glb is imported by Blender's glTF importer as is and its vertices must lie
within a voxel of the volume's mesh (the two overlap in one scene).

OpenVDB (the `openvdb` module in Blender's bundled site-packages): the grid must read back with
class level set, background 3 voxels, `is_saved_as_half_float` false, and its values, copied
into a dense array over the sidecar's grid, must agree with volume.npy: equal (to float32
rounding) at active voxels, and the same sign everywhere (inactive voxels and tiles hold
± the background).

Prints one JSON line with the figures and a "problems" list; exits 0 when there are no
problems, 1 otherwise, 2 when bpy is not installed.
"""

import argparse
import glob
import json
import os
import sys


def openvdb_module(bpy):
    """The `openvdb` module bundled with Blender, or None."""
    # bpy/<version>/scripts/modules/bpy/__init__.py -> bpy/<version>/python/lib/python3.*/...
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(bpy.__file__))))
    for path in glob.glob(os.path.join(root, "python", "lib", "python3*", "site-packages")):
        if path not in sys.path:
            sys.path.append(path)
    try:
        import openvdb

        return openvdb
    except ImportError:
        return None


def to_blender(points, up, scale):
    """Input coordinates (N×3) to Blender's frame, as the glb is imported."""
    import numpy as np

    p = np.asarray(points, dtype=np.float64) * scale
    if up == "y":
        return np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)
    return p


def expected_matrix(side, up, scale):
    """Index-to-world matrix of the vdb (4×4) implied by the sidecar."""
    import numpy as np

    h = side["voxel_size"] * scale
    o = [c * scale for c in side["origin"]]
    nz = side["shape"][2]
    last_z = ((nz + 7) // 8) * 8 - 1
    t = [o[0], -o[2] - h * last_z, o[1]] if up == "y" else o
    m = np.diag([h, h, h, 1.0])
    m[:3, 3] = t
    return m, last_z


def mesh_arrays(obj, matrix=True):
    import numpy as np

    mesh = obj.data
    verts = np.array([tuple(v.co) for v in mesh.vertices], dtype=np.float64)
    if matrix:
        mw = np.array(obj.matrix_world)
        verts = verts @ mw[:3, :3].T + mw[:3, 3]
    polys = [tuple(p.vertices) for p in mesh.polygons]
    return verts, polys


def surface_distances(points, verts, polys):
    """Distance from each point to the surface (verts, polys), by a BVH tree."""
    import numpy as np
    from mathutils import Vector
    from mathutils.bvhtree import BVHTree

    tree = BVHTree.FromPolygons([tuple(v) for v in verts], polys)
    out = np.empty(len(points))
    for i, p in enumerate(points):
        hit = tree.find_nearest(Vector(p))
        out[i] = hit[3] if hit[0] is not None else np.inf
    return out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("vdb")
    parser.add_argument("ply")
    parser.add_argument("sidecar")
    parser.add_argument("--up", choices=["y", "z"], default="y")
    parser.add_argument("--metres-per-unit", type=float, default=1.0)
    parser.add_argument("--glb", help="the run's mesh.glb, imported as is: it must overlap")
    args = parser.parse_args()
    try:
        import bpy
    except ImportError:
        print("bpy is not installed; run bash tools/install-validators.sh", file=sys.stderr)
        return 2
    import numpy as np

    # Blender prints its own messages on stdout: send them to stderr, so that stdout holds
    # only the report line.
    stdout = os.dup(1)
    os.dup2(2, 1)
    scale = args.metres_per_unit
    with open(args.sidecar) as f:
        side = json.load(f)
    h = side["voxel_size"] * scale
    problems = []
    report = {"file": args.vdb}

    bpy.ops.wm.read_factory_settings(use_empty=True)
    vdb = os.path.abspath(args.vdb)
    bpy.ops.object.volume_import(
        filepath=vdb, directory=os.path.dirname(vdb), files=[{"name": os.path.basename(vdb)}]
    )
    volumes = [o for o in bpy.data.objects if o.type == "VOLUME"]
    if len(volumes) != 1:
        problems.append(f"{len(volumes)} volume objects after the import, expected 1")
        report["problems"] = problems
        sys.stdout.flush()
        os.dup2(stdout, 1)
        print(json.dumps(report), flush=True)
        return 1
    vol_obj = volumes[0]
    vol = vol_obj.data
    vol.grids.load()
    grids = [(g.name, g.data_type) for g in vol.grids]
    report["grids"] = grids
    if grids != [("surface", "FLOAT")]:
        problems.append(f"grids are {grids}, expected one float grid named surface")
    expected, last_z = expected_matrix(side, args.up, scale)
    if vol.grids:
        grid = vol.grids[0]
        m = np.array(grid.matrix_object)
        report["matrix_object"] = m.tolist()
        err = float(np.abs(m - expected).max())
        report["matrix_error"] = err
        if err > 1e-6 * max(1.0, np.abs(expected).max()):
            problems.append(f"matrix_object differs from the expected transform by {err}")

    # Volume to Mesh at threshold 0, at the grid's resolution.
    mesh_obj = bpy.data.objects.new("from_volume", bpy.data.meshes.new("from_volume"))
    bpy.context.scene.collection.objects.link(mesh_obj)
    mod = mesh_obj.modifiers.new("volume_to_mesh", "VOLUME_TO_MESH")
    mod.object = vol_obj
    mod.grid_name = "surface"
    mod.threshold = 0.0
    mod.resolution_mode = "GRID"
    mod.adaptivity = 0.0
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = mesh_obj.evaluated_get(depsgraph)
    from_volume = evaluated.to_mesh()
    vv = np.array([tuple(v.co) for v in from_volume.vertices], dtype=np.float64)
    vp = [tuple(p.vertices) for p in from_volume.polygons]
    report["volume_mesh_vertices"] = len(vv)

    bpy.ops.wm.ply_import(filepath=os.path.abspath(args.ply))
    plys = [o for o in bpy.data.objects if o.type == "MESH" and o is not mesh_obj]
    if len(plys) != 1 or len(vv) == 0:
        problems.append(f"{len(plys)} PLY objects and {len(vv)} volume-mesh vertices")
    else:
        pv, pp = mesh_arrays(plys[0])
        pv = to_blender(pv, args.up, scale)
        a = surface_distances(vv, pv, pp) / h
        b = surface_distances(pv, vv, vp) / h
        report["volume_to_ply_voxels"] = {"max": float(a.max()), "mean": float(a.mean())}
        report["ply_to_volume_voxels"] = {"max": float(b.max()), "mean": float(b.mean())}
        if a.max() > 1.0 or b.max() > 1.0 or a.mean() > 0.25 or b.mean() > 0.25:
            problems.append("the volume's zero set is over 1 voxel (max) or 0.25 (mean) from the PLY")

    if args.glb and len(vv):
        before = set(bpy.data.objects)
        bpy.ops.import_scene.gltf(filepath=os.path.abspath(args.glb))
        glbs = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
        if len(glbs) != 1:
            problems.append(f"{len(glbs)} meshes imported from the glb, expected 1")
        else:
            gv, _ = mesh_arrays(glbs[0])
            c = surface_distances(gv, vv, vp) / h
            report["glb_to_volume_voxels"] = {"max": float(c.max()), "mean": float(c.mean())}
            if c.max() > 1.0:
                problems.append("the glb, imported by Blender, is over 1 voxel from the volume")

    openvdb = openvdb_module(bpy)
    npy_path = os.path.join(os.path.dirname(os.path.abspath(args.sidecar)), side["data"])
    if openvdb is None:
        problems.append("the openvdb module is not in Blender's site-packages")
    else:
        g = openvdb.read(vdb, "surface")
        report["openvdb"] = {
            "class": str(g.gridClass),
            "background": float(g.background),
            "active_voxels": int(g.activeVoxelCount()),
            "half_float": bool(g.saveFloatAsHalf),
            "metadata": sorted(g.metadata.keys()),
        }
        if "LEVEL_SET" not in str(g.gridClass).upper().replace(" ", "_"):
            problems.append(f"grid class {g.gridClass}, expected level set")
        if abs(g.background - 3 * h) > 1e-6 * h:
            problems.append(f"background {g.background}, expected {3 * h}")
        if g.saveFloatAsHalf:
            problems.append("saved as half float")
        dense = np.load(npy_path) * scale
        nx, ny, nz = dense.shape
        # The npy in the vdb's index frame: index (i, last_z - k, j) with --up y.
        if args.up == "y":
            want = np.full((nx, last_z + 1, ny), np.nan, dtype=np.float64)
            want[:, last_z - np.arange(nz), :] = np.transpose(dense, (0, 2, 1))
        else:
            want = dense.astype(np.float64)
        got = np.zeros(want.shape, dtype=np.float32)
        g.copyToArray(got, ijk=(0, 0, 0))
        known = ~np.isnan(want)
        band = known & (np.abs(want) < 3 * h * (1 - 1e-6))
        diff = np.abs(got[band] - want[band])
        report["band_max_difference_voxels"] = float(diff.max() / h) if diff.size else None
        sign_mismatch = int((np.sign(got[known]) != np.sign(want[known])).sum())
        report["sign_mismatches"] = sign_mismatch
        if diff.size == 0 or diff.max() > 1e-5 * max(h, np.abs(want[band]).max()):
            problems.append("active values differ from volume.npy")
        if sign_mismatch:
            problems.append(f"{sign_mismatch} voxels have another sign than in volume.npy")
        if np.abs(got).max() > 3 * h * (1 + 1e-6):
            problems.append("a value exceeds the background")
    report["problems"] = problems
    sys.stdout.flush()
    os.dup2(stdout, 1)
    print(json.dumps(report), flush=True)
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
