"""Validates a PLY file written by stablesurf with two independent readers.

Usage: python tools/validate/ply.py FILE.ply [--closed] [--self-intersections]

1. plyfile, read strictly: the header must declare exactly the elements and properties stablesurf
   writes (vertex x y z nx ny nz float, optional red green blue uchar, optional quality float; face vertex_indices as a list of
   uchar count and int indices), the body must hold exactly the declared data with no trailing
   bytes, every face must be a triangle with indices in range, and every float must be finite.
2. pymeshlab (MeshLab's own loader): loads the file and reports its topology. With --closed the
   mesh must be watertight (no boundary edges) and two-manifold (no non-manifold edges or
   vertices). With --self-intersections, MeshLab's own test selects the faces that intersect
   another (`compute_selection_by_self_intersections_per_face`); their number is reported as
   `self_intersecting_faces` (a report, not a failure: MeshLab's test is not exact, see the
   README's note on the synthetic cube).

Prints one JSON line with what both readers saw and exits 0 when every check passed, 1 when a
check failed, 2 when a reader could not be imported.
"""

import json
import math
import sys

EXPECTED_VERTEX = ["x", "y", "z", "nx", "ny", "nz"]
COLOURS = ["red", "green", "blue"]


def check_plyfile(path, problems):
    import numpy as np
    from plyfile import PlyData

    with open(path, "rb") as stream:
        data = PlyData.read(stream, mmap=False)
        if not data.text:
            trailing = stream.read()
            if trailing:
                problems.append(f"{len(trailing)} bytes after the last element")
    if data.text:
        # plyfile wraps the stream for text, so count the body's lines directly: one per element.
        with open(path, "rb") as stream:
            body = stream.read().split(b"end_header", 1)[-1]
        lines = [line for line in body.splitlines() if line.strip()]
        expected = sum(e.count for e in data.elements)
        if len(lines) != expected:
            problems.append(f"{len(lines)} data lines, header declares {expected}")
    names = [e.name for e in data.elements]
    if names != ["vertex", "face"]:
        problems.append(f"elements are {names}, expected ['vertex', 'face']")
        return {"elements": names}
    vertex, face = data["vertex"], data["face"]
    props = [(p.name, p.val_dtype) for p in vertex.properties]
    prop_names = [p[0] for p in props]
    allowed = [
        EXPECTED_VERTEX + colours + quality
        for colours in ([], COLOURS)
        for quality in ([], ["quality"])
    ]
    if prop_names not in allowed:
        problems.append(f"vertex properties are {prop_names}")
    for name, dtype in props:
        expected = "u1" if name in COLOURS else "f4"
        if dtype != expected:
            problems.append(f"vertex property {name} has type {dtype}, expected {expected}")
    face_props = face.properties
    if len(face_props) != 1 or face_props[0].name != "vertex_indices":
        problems.append(f"face properties are {[p.name for p in face_props]}")
    elif (face_props[0].len_dtype, face_props[0].val_dtype) != ("u1", "i4"):
        problems.append(
            f"vertex_indices is list {face_props[0].len_dtype} {face_props[0].val_dtype}, "
            "expected list uchar int"
        )
    n_vertices = vertex.count
    for name in prop_names:
        values = np.asarray(vertex[name], dtype=np.float64)
        if not np.all(np.isfinite(values)):
            problems.append(f"vertex property {name} has non-finite values")
    normals = np.stack([vertex[n] for n in ("nx", "ny", "nz")], axis=1).astype(np.float64)
    if n_vertices:
        length_error = float(np.max(np.abs(np.linalg.norm(normals, axis=1) - 1.0)))
        if length_error > 1e-5:
            problems.append(f"normals deviate from unit length by {length_error}")
    faces = face["vertex_indices"]
    bad_len = sum(1 for f in faces if len(f) != 3)
    if bad_len:
        problems.append(f"{bad_len} faces are not triangles")
    if len(faces):
        flat = np.concatenate([np.asarray(f) for f in faces])
        if flat.min() < 0 or flat.max() >= n_vertices:
            problems.append("face indices out of range")
    summary = {
        "format": "ascii" if data.text else data.byte_order,
        "vertices": int(n_vertices),
        "faces": int(face.count),
        "vertex_properties": prop_names,
    }
    if "quality" in prop_names:
        q = np.asarray(vertex["quality"], dtype=np.float64)
        summary["quality_min"] = float(q.min()) if len(q) else 0.0
        summary["quality_max"] = float(q.max()) if len(q) else 0.0
    return summary


def check_pymeshlab(path, closed, problems, self_intersections=False):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(path)
    mesh = ms.current_mesh()
    topo = ms.get_topological_measures()
    summary = {
        "vertices": mesh.vertex_number(),
        "faces": mesh.face_number(),
        "has_vertex_quality": bool(mesh.has_vertex_scalar()),
        "has_vertex_colour": bool(mesh.has_vertex_color()),
    }
    for key in (
        "boundary_edges",
        "connected_components_number",
        "is_mesh_two_manifold",
        "non_two_manifold_edges",
        "non_two_manifold_vertices",
        "genus",
    ):
        value = topo.get(key)
        summary[key] = value if not isinstance(value, float) or math.isfinite(value) else None
    summary["watertight"] = topo.get("boundary_edges") == 0
    if summary["has_vertex_quality"] and mesh.vertex_number():
        q = mesh.vertex_scalar_array()
        summary["quality_min"] = float(q.min())
        summary["quality_max"] = float(q.max())
    if self_intersections:
        ms.compute_selection_by_self_intersections_per_face()
        summary["self_intersecting_faces"] = int(ms.current_mesh().selected_face_number())
    if closed:
        if not summary["watertight"]:
            problems.append(f"meshlab: {topo.get('boundary_edges')} boundary edges (not watertight)")
        if not topo.get("is_mesh_two_manifold"):
            problems.append("meshlab: mesh is not two-manifold")
        if topo.get("non_two_manifold_edges", 0) or topo.get("non_two_manifold_vertices", 0):
            problems.append("meshlab: non-manifold edges or vertices")
    return summary


def main():
    args = sys.argv[1:]
    closed = "--closed" in args
    files = [a for a in args if not a.startswith("--")]
    if len(files) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    path = files[0]
    problems = []
    try:
        import plyfile  # noqa: F401
        import pymeshlab  # noqa: F401
    except ImportError as err:
        print(f"validator not installed: {err}", file=sys.stderr)
        return 2
    report = {"file": path}
    try:
        report["plyfile"] = check_plyfile(path, problems)
    except Exception as err:  # a parse failure is a validation failure
        problems.append(f"plyfile: {type(err).__name__}: {err}")
    try:
        report["pymeshlab"] = check_pymeshlab(
            path, closed, problems, "--self-intersections" in args
        )
    except Exception as err:
        problems.append(f"pymeshlab: {type(err).__name__}: {err}")
    if "plyfile" in report and "pymeshlab" in report:
        a, b = report["plyfile"], report["pymeshlab"]
        if (a.get("vertices"), a.get("faces")) != (b["vertices"], b["faces"]):
            problems.append("plyfile and pymeshlab disagree on vertex/face counts")
    report["problems"] = problems
    print(json.dumps(report))
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
