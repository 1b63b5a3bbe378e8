#!/usr/bin/env python3
"""stablesurf against Poisson surface reconstruction, side by side in one run.

Run through the wrapper `tools/bench_peers [--quick] [--bin PATH]` (it builds the release binary,
unless --bin names one, and the synthetic inputs, then calls this script in tools/validate/.venv).
The table answers the acceptance criteria of the default `run` (detail mode): 0 self-intersecting
faces (MeshLab), one watertight manifold component per object, the input's genus on watertight
inputs, no piece farther than 2% of the diagonal from every point, Chamfer <= 1.0x Open3D Poisson
depth 8 on the same points and normals, CPU <= 0.5x Poisson's whole process.

Inputs: the synthetic shapes with exact normals (written by bench_peers_inputs; --quick: the torus
only), then every mesh file of ../shared/data except bun000.ply (one raw range view) and
bunny-scans/: bunny_zipper (as "bunny"), duck, spot, fertility, max_planck, patella_vhf_left,
quadknot, fandisk, teapot, each turned into oriented points by `stablesurf normals FILE -o
NAME_oriented.ply -q`; then the 1M-point torus when its file exists. Every method gets the same
file of points and normals. The genus and watertightness of each original file (pymeshlab's
topological measures) are shown with its name.

Per input, four reconstructions, each in its own child process, in this order:
  - stablesurf default: stablesurf run INPUT -o DIR --no-cache -q --formats ply,json (detail mode)
  - stablesurf global:  the same with --mode global
  - Open3D Poisson d8:  TriangleMesh.create_from_point_cloud_poisson(depth=8), raw output
  - pymeshlab screened Poisson d8: generate_surface_reconstruction_screened_poisson(depth=8), raw
The peers run with OMP_WAIT_POLICY=passive. Open3D Poisson d8 is the reference of the ratios.

Measures (one tool for all):
  - CPU seconds: user + sys of the child process (resource.getrusage(RUSAGE_CHILDREN) deltas),
    whole process (start-up, reading, writing included); CPU / Open3D = CPU of the method / CPU of
    Open3D Poisson d8's whole process.
  - on the written mesh with pymeshlab: triangles; self-intersecting faces (the count selected by
    compute_selection_by_self_intersections_per_face); watertight, manifold, connected components
    and genus from get_topological_measures (manifold: no non-manifold edge or vertex; watertight:
    manifold and no boundary edge; genus shown for watertight meshes only).
  - far pieces: pieces of the mesh (faces connected through shared vertices) of which no vertex
    and no area sample lies within 2% of the input's bounding-box diagonal of an input point.
  - Hausdorff mesh -> data: largest distance from every vertex and from 1M area-uniform mesh
    samples to the nearest input point.
  - accuracy:
      synthetic inputs: RMS distance to the exact analytic surface, two-sided: the 1M mesh
        samples -> exact surface (closed form for sphere, torus and cube; Newton projection onto
        f = 0 otherwise, capped by the distance to the nearest exact sample), plus the exact input
        points -> mesh; one RMS over both sets.
      every input: symmetric Chamfer distance = (mean distance input points -> mesh + mean
        distance of the 1M mesh samples -> nearest input point) / 2; Chamfer / Open3D. With 1M
        samples the second mean varies by about 0.04% between seeds (100k: 0.12%, as large as
        the gaps between methods on the synthetic shapes).
    Distances are divided by the input's bounding-box diagonal. Point-to-mesh distances are exact
    (Open3D RaycastingScene); nearest points by k-d tree (scipy).
  - the summary counts, per criterion, the inputs on which stablesurf default (and Open3D, for
    the criteria that are not ratios to it) meets it, and names per input the failing ones.
"""

import argparse
import datetime
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SYNTHETIC = ["sphere", "torus", "eight", "heart", "cube", "twisted"]
SYNTHETIC_GENUS = {"sphere": 0, "torus": 1, "eight": 0, "heart": 0, "cube": 0, "twisted": 0}
METHODS = ["stablesurf default", "stablesurf global", "Open3D Poisson d8", "pymeshlab screened Poisson d8"]
REF = "Open3D Poisson d8"  # the reference of the ratio columns and of the summary
MESH_DIRS = {"stablesurf default": "stablesurf-default", "stablesurf global": "stablesurf-global",
             "Open3D Poisson d8": "open3d", "pymeshlab screened Poisson d8": "pymeshlab"}
TIMEOUT = 300


# ---------------------------------------------------------------- peers (run in a child process)

def peer_main(which, inp, out):
    """Child: reconstruct INPUT with a peer and write OUT (PLY); prints nothing on success."""
    if which == "open3d":
        import open3d as o3d

        pc = o3d.io.read_point_cloud(inp)
        if not pc.has_normals():
            raise SystemExit("input has no normals")
        mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=8)
        o3d.io.write_triangle_mesh(out, mesh)
    elif which == "pymeshlab":
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.load_new_mesh(inp)
        ms.generate_surface_reconstruction_screened_poisson(depth=8)
        ms.save_current_mesh(out)
    else:
        raise SystemExit(f"unknown peer {which}")


# ---------------------------------------------------------------- exact surfaces

def implicit(name, p):
    import numpy as np

    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if name == "sphere":
        return x * x + y * y + z * z - 1.0
    if name == "torus":
        q = np.sqrt(x * x + y * y) - 1.0
        return q * q + z * z - 0.16
    if name == "eight":
        return x**4 - 1.5 * x * x + y * y + z * z - 0.1
    if name == "heart":
        a = x * x + 2.25 * y * y + z * z - 1.0
        return a**3 - x * x * z**3 - 9.0 / 80.0 * y * y * z**3
    if name == "twisted":
        t = 0.8 * z
        s, c = np.sin(t), np.cos(t)
        u = c * x + s * y
        v = -s * x + c * y
        return u * u + v * v / 0.16 + z * z / 2.25 - 1.0
    raise ValueError(name)


def exact_distance(name, p, exact_points_tree):
    """Distance from points p (n x 3) to the exact surface of a synthetic shape."""
    import numpy as np

    if name == "sphere":
        return np.abs(np.linalg.norm(p, axis=1) - 1.0)
    if name.startswith("torus"):
        q = np.sqrt(p[:, 0] ** 2 + p[:, 1] ** 2) - 1.0
        return np.abs(np.sqrt(q * q + p[:, 2] ** 2) - 0.4)
    if name == "cube":
        a = np.abs(p) - 1.0
        outside = np.linalg.norm(np.maximum(a, 0.0), axis=1)
        inside = np.minimum(a.max(axis=1), 0.0)
        return np.abs(outside + inside)
    # Newton projection onto f = 0 (an upper bound on the distance once converged), capped by the
    # distance to the nearest exact sample (also an upper bound).
    h = 1e-6
    q = p.copy()
    for _ in range(40):
        f = implicit(name, q)
        g = np.empty_like(q)
        for a in range(3):
            e = np.zeros(3)
            e[a] = h
            g[:, a] = (implicit(name, q + e) - implicit(name, q - e)) / (2 * h)
        gg = (g * g).sum(axis=1)
        ok = gg > 1e-300
        step = np.zeros_like(q)
        step[ok] = (f[ok] / gg[ok])[:, None] * g[ok]
        # Limit the step so a vanishing gradient cannot throw the point far away.
        n = np.linalg.norm(step, axis=1)
        big = n > 0.1
        step[big] *= (0.1 / n[big])[:, None]
        q = q - step
    f = implicit(name, q)
    g = np.empty_like(q)
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        g[:, a] = (implicit(name, q + e) - implicit(name, q - e)) / (2 * h)
    converged = np.abs(f) <= 1e-9 * np.maximum(np.linalg.norm(g, axis=1), 1e-300)
    newton = np.where(converged, np.linalg.norm(q - p, axis=1), np.inf)
    nearest, _ = exact_points_tree.query(p)
    return np.minimum(newton, nearest)


# ---------------------------------------------------------------- measuring

FAR = 0.02  # a piece is "far" when none of it comes within FAR x diagonal of an input point


def topology(ms):
    """Watertight / manifold / components / genus from pymeshlab's topological measures."""
    topo = ms.get_topological_measures()
    faces = int(topo["faces_number"])
    manifold = bool(topo["is_mesh_two_manifold"]) and topo["non_two_manifold_edges"] == 0 and topo["non_two_manifold_vertices"] == 0
    watertight = manifold and topo["boundary_edges"] == 0 and faces > 0
    genus = int(topo["genus"]) if manifold and faces > 0 and int(topo["genus"]) >= 0 else None
    return {
        "triangles": faces,
        "watertight": watertight,
        "manifold": manifold,
        "components": int(topo["connected_components_number"]),
        "boundary_edges": int(topo["boundary_edges"]),
        "genus": genus if watertight else None,
        "genus_any": genus,
    }


def self_intersections(ms):
    """Faces MeshLab selects as self-intersecting."""
    ms.set_selection_none()
    ms.compute_selection_by_self_intersections_per_face()
    n = int(ms.current_mesh().selected_face_number())
    ms.set_selection_none()
    return n


def input_topology(path):
    """Genus and watertightness of an original file of ../shared/data (pymeshlab, as loaded)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    t = topology(ms)
    return {"watertight": t["watertight"], "manifold": t["manifold"], "genus": t["genus_any"],
            "boundary_edges": t["boundary_edges"], "components": t["components"]}


def face_components(n_verts, tris):
    """Connected component label of every face (faces sharing a vertex are connected)."""
    import numpy as np
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    i = np.concatenate([tris[:, 0], tris[:, 1]])
    j = np.concatenate([tris[:, 1], tris[:, 2]])
    g = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(n_verts, n_verts))
    _, labels = connected_components(g, directed=False)
    return labels[tris[:, 0]]


def measure(name, input_points, tree, mesh_path, synthetic):
    import numpy as np
    import open3d as o3d
    import pymeshlab
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(mesh_path))
    res = topology(ms)
    res.pop("genus_any")
    if res["triangles"] == 0:
        return res
    res["self_intersections"] = self_intersections(ms)
    m = ms.current_mesh()
    verts = np.asarray(m.vertex_matrix(), dtype=np.float64)
    tris = np.asarray(m.face_matrix(), dtype=np.int64)
    samples, sample_face = sample_mesh(verts, tris, MESH_SAMPLES)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))
    pts = input_points
    if len(pts) > 200_000:
        pts = pts[:: len(pts) // 200_000]
    d_in = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().astype(np.float64)
    d_out, _ = tree.query(samples)
    lo, hi = input_points.min(axis=0), input_points.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    res["chamfer_rel"] = 0.5 * (d_in.mean() + d_out.mean()) / diag
    # Far pieces and Hausdorff mesh -> data: every vertex used by a face plus the area samples.
    used = np.unique(tris)
    d_vert = np.full(len(verts), np.inf)
    d_vert[used], _ = tree.query(verts[used])
    face_label = face_components(len(verts), tris)
    vert_label = np.full(len(verts), -1)
    vert_label[tris.ravel()] = np.repeat(face_label, 3)
    labels, dense = np.unique(face_label, return_inverse=True)
    closest = np.full(len(labels), np.inf)
    np.minimum.at(closest, np.searchsorted(labels, vert_label[used]), d_vert[used])
    np.minimum.at(closest, dense[sample_face], d_out)
    res["pieces"] = int(len(labels))
    res["far_pieces"] = int((closest > FAR * diag).sum())
    res["far_pieces_max_rel"] = float(closest.max() / diag)
    res["hausdorff_rel"] = float(max(d_out.max(), d_vert[used].max()) / diag)
    if synthetic:
        d_exact = exact_distance(name, samples, tree)
        both = np.concatenate([d_exact, d_in])
        res["rms_exact_rel"] = float(np.sqrt((both * both).mean()) / diag)
    return res


# Area samples of every mesh: the mean distance from them to the input varies by about 0.04%
# between seeds at 1M (0.12% at 100k, as large as the gaps between methods on smooth shapes).
MESH_SAMPLES = 1_000_000


def sample_mesh(verts, tris, n):
    """n points uniformly distributed by area on the mesh (fixed seed), and the face of each."""
    import numpy as np

    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(2008)
    if area.sum() > 0:
        t = rng.choice(len(tris), size=n, p=area / area.sum())
    else:
        t = rng.integers(0, len(tris), size=n)
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    return (1 - r1) * a[t] + r1 * (1 - r2) * b[t] + r1 * r2 * c[t], t


def read_points(path):
    import numpy as np
    import open3d as o3d

    return np.asarray(o3d.io.read_point_cloud(str(path)).points, dtype=np.float64)


# ---------------------------------------------------------------- running

def cpu_of_children():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_child(cmd, env):
    c0 = cpu_of_children()
    w0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, timeout=TIMEOUT, text=True)
        ok, err = p.returncode == 0, p.stderr.strip().splitlines()[-1:] if p.returncode else []
    except subprocess.TimeoutExpired:
        ok, err = False, [f"timeout after {TIMEOUT} s"]
    return ok, cpu_of_children() - c0, time.perf_counter() - w0, (err[0] if err else "")


def python_baseline(env):
    """CPU of a child that only imports the peer libraries (start-up cost inside the peers' figures)."""
    out = {}
    for lib in ["open3d", "pymeshlab"]:
        _, cpu, _, _ = run_child([sys.executable, "-c", f"import {lib}"], env)
        out[lib] = cpu
    return out


# Files of ../shared/data that run, in this order, under these names (the rest of the folder:
# bun000.ply, a single raw range view, and bunny-scans/, registered raw views, are not meshes to
# compare here). Any other mesh or scan file found there runs after these, under its stem.
REAL = [("bunny", "bunny_zipper.ply"), ("duck", "duck.ply"), ("spot", "spot.obj"),
        ("fertility", "fertility.ply"), ("max_planck", "max_planck.obj"),
        ("patella_vhf_left", "patella_vhf_left.ply"), ("quadknot", "quadknot.obj"),
        ("fandisk", "fandisk.obj"), ("teapot", "teapot.obj")]
NOT_REAL = {"bun000.ply"}
SCAN_EXT = {".ply", ".obj", ".off", ".stl", ".xyz", ".pts", ".txt", ".csv", ".las", ".laz", ".e57", ".glb", ".gltf"}


def real_inputs(data):
    """(name, path) of every mesh or scan file of DATA that the table covers."""
    out = [(n, data / f) for n, f in REAL if (data / f).exists()]
    known = {f for _, f in REAL} | NOT_REAL
    if data.is_dir():
        for f in sorted(data.iterdir()):
            if f.is_file() and f.suffix.lower() in SCAN_EXT and f.name not in known:
                out.append((f.stem, f))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--inputs", help="directory with the synthetic input PLYs")
    ap.add_argument("--bin", help="the stablesurf binary")
    ap.add_argument("--out", help="the Markdown file to write")
    ap.add_argument("--work", help="scratch directory for outputs")
    ap.add_argument("--only", help=argparse.SUPPRESS)  # NAME,NAME: run only these inputs (partial tables)
    ap.add_argument("--peer", nargs=3, metavar=("WHICH", "IN", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.peer:
        peer_main(*a.peer)
        return
    if not (a.inputs and a.bin and a.out and a.work):
        ap.error("--inputs, --bin, --out and --work are required")
    import numpy as np  # noqa: F401

    only = set(a.only.split(",")) if a.only else None
    start = time.perf_counter()
    work = Path(a.work)
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    data = ROOT.parent / "shared" / "data"
    inputs = []  # (name, path, synthetic, input facts)
    shapes = ["torus"] if a.quick else SYNTHETIC
    for s in shapes:
        if only is None or s in only:
            inputs.append((s, Path(a.inputs) / f"{s}.ply", True, {"watertight": True, "genus": SYNTHETIC_GENUS[s]}))
    if not a.quick:
        if not data.is_dir():
            print(f"bench_peers: {data} not found, real inputs skipped", file=sys.stderr)
        for name, src in real_inputs(data):
            if only is not None and name not in only:
                continue
            dst = work / f"{name}_oriented.ply"
            ok, _, _, err = run_child([a.bin, "normals", str(src), "-o", str(dst), "-q"], os.environ.copy())
            if not ok:
                print(f"bench_peers: normals for {name} failed: {err}", file=sys.stderr)
                continue
            try:
                facts = input_topology(src)
            except Exception as e:  # a file pymeshlab cannot read
                facts = {"watertight": False, "genus": None, "error": str(e)}
            facts["file"] = src.name
            inputs.append((name, dst, False, facts))
        big = Path(a.inputs) / "torus_1m.ply"
        if big.exists() and (only is None or "torus_1m" in only):
            inputs.append(("torus_1m", big, True, {"watertight": True, "genus": 1}))

    ours_env = os.environ.copy()
    peer_env = dict(os.environ, OMP_WAIT_POLICY="passive")
    baseline = python_baseline(peer_env)
    rows = []
    for name, path, synthetic, facts in inputs:
        from scipy.spatial import cKDTree

        pts = read_points(path)
        tree = cKDTree(pts)
        results = {}
        for method in METHODS:
            out_dir = work / name / MESH_DIRS[method]
            mesh = out_dir / "mesh.ply"
            if method.startswith("stablesurf"):
                cmd = [a.bin, "run", str(path), "-o", str(out_dir), "--no-cache", "-q", "--formats", "ply,json"]
                if method == "stablesurf global":
                    cmd += ["--mode", "global"]
                env = ours_env
            else:
                which = MESH_DIRS[method]
                out_dir.mkdir(parents=True, exist_ok=True)
                cmd = [sys.executable, str(Path(__file__).resolve()), "--peer", which, str(path), str(mesh)]
                env = peer_env
            ok, cpu, wall, err = run_child(cmd, env)
            r = {"ok": ok and mesh.exists(), "cpu": cpu, "wall": wall, "error": err}
            if r["ok"]:
                try:
                    r.update(measure(name, pts, tree, mesh, synthetic))
                except Exception as e:  # a mesh the measuring tools cannot read
                    r["ok"] = False
                    r["error"] = f"measure: {e}"
            results[method] = r
            print(f"bench_peers: {name:10s} {method:30s} {'ok' if r['ok'] else 'FAILED ' + r['error']} cpu {cpu:.2f} s", file=sys.stderr)
        rows.append((name, len(pts), synthetic, facts, results))
    scan_lines, scan_rows = [], []
    if not a.quick and (only is None or "scans" in only):
        sys.path.insert(0, str(HERE))
        import bench_scans

        scan_rows = bench_scans.run(a.bin, work / "scans")
        scan_lines = bench_scans.section(a.bin, scan_rows, a.out, work / "scans")
    total = time.perf_counter() - start
    sys.path.insert(0, str(HERE))
    import bench_scale
    import bench_noise

    # The sections of tools/bench_scale.py and tools/bench_noise, kept as they are.
    kept = [bench_scale.existing_section(a.out), bench_noise.existing_section(a.out)]
    write_doc(a, rows, baseline, total)
    if scan_lines:
        with open(a.out, "a") as f:
            f.write("\n".join(scan_lines) + "\n")
    for section in kept:
        if section:
            with open(a.out, "a") as f:
                f.write("\n" + section)
    (Path(a.out).with_suffix(".json")).write_text(json.dumps({"rows": rows, "scans": scan_rows, "baseline": baseline, "total_wall_s": total}, indent=1, default=str))
    print(a.out)


def machine():
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}; load average at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1/5/15 min)"


def versions():
    from importlib.metadata import version

    out = []
    for p in ["open3d", "pymeshlab", "numpy", "scipy"]:
        try:
            out.append(f"{p} {version(p)}")
        except Exception:
            out.append(f"{p} missing")
    return ", ".join(out)


def input_cell(name, synthetic, facts):
    if synthetic:
        return f"{name} (exact surface, genus {facts['genus']})"
    if "error" in facts:
        return f"{name} (unreadable by pymeshlab)"
    g = f"genus {facts['genus']}, " if facts.get("genus") is not None else ""
    if facts["watertight"]:
        return f"{name} ({g}watertight)"
    extra = "" if facts.get("manifold") else ", non-manifold"
    return f"{name} ({g}not watertight: {facts['boundary_edges']} boundary edges{extra})"


def fmt(v, f):
    return "-" if v is None else format(v, f)


def write_doc(a, rows, baseline, total):
    d = []
    d.append("# stablesurf against Poisson reconstruction\n")
    d.append(
        f"Generated by `tools/bench_peers{' --quick' if a.quick else ''}`"
        f"{' (partial: only ' + ', '.join(a.only.split(',')) + ')' if a.only else ''} on "
        f"{datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, total {total:.0f} s wall. "
        f"Machine: {machine()}. Peers: {versions()}. Do not edit by hand; regenerate with "
        "`bash tools/bench_peers_install.sh && tools/bench_peers` (the install step sets up Open3D, pymeshlab "
        "and scipy in tools/validate/.venv).\n"
    )
    d.append(
        "**What it checks.** The acceptance criteria of the default `run`: on every file of ../shared/data, "
        "0 self-intersecting faces (MeshLab), one watertight manifold component per object, the input's genus on "
        "watertight inputs, no piece farther than 2% of the diagonal from every point, Chamfer ≤ 1.0× Open3D "
        "Poisson depth 8 on the same points and normals, CPU ≤ 0.5× Poisson's whole process. The summary below "
        "counts where each holds.\n"
    )
    d.append(
        "**What runs.** Inputs: the synthetic shapes (20,000 points with exact normals written by "
        "`bench_peers_inputs`; with `--quick` the torus only), then every mesh file of ../shared/data except "
        "`bun000.ply` (one raw range view) and `bunny-scans/` (raw views): bunny (`bunny_zipper.ply`), duck, spot, "
        "fertility, max_planck, patella_vhf_left, quadknot, fandisk, teapot, each turned into oriented points by "
        "`stablesurf normals FILE -o NAME_oriented.ply -q` (the normals `run` computes itself), and a "
        "1,000,000-point torus when its file exists. All four methods get that same file of points and normals. "
        "*stablesurf default* is `stablesurf run INPUT -o DIR --no-cache -q --formats ply,json` (no `--mode`: "
        "detail mode, the product's default); *stablesurf global* adds `--mode global`. *Open3D Poisson d8* is "
        "`TriangleMesh.create_from_point_cloud_poisson(depth=8)`, *pymeshlab screened Poisson d8* is "
        "`generate_surface_reconstruction_screened_poisson(depth=8)`, both raw (no density trimming), each in "
        "its own Python process with `OMP_WAIT_POLICY=passive`. The input cell gives the genus and "
        "watertightness of the original file of ../shared/data (pymeshlab's topological measures, as loaded).\n"
    )
    d.append(
        "**Measures.** *CPU s*: user + sys of the child process (getrusage RUSAGE_CHILDREN), whole process "
        "(start-up, reading, writing included); for the peers it includes Python start-up and the library "
        f"import (measured alone: Open3D {baseline.get('open3d', float('nan')):.2f} s, pymeshlab "
        f"{baseline.get('pymeshlab', float('nan')):.2f} s). *CPU / Open3D*: CPU of the method / CPU of Open3D "
        "Poisson d8's whole process on the same input. On the written mesh, with pymeshlab: *tri.*: triangles; "
        "*self-int.*: faces selected by `compute_selection_by_self_intersections_per_face`; *watertight* / "
        "*manifold*: from `get_topological_measures` (manifold: no non-manifold edge or vertex; watertight: "
        "manifold without boundary edges); *comp.*: its connected components; *genus*: its genus, given for "
        "watertight meshes only. *far pieces*: pieces of the mesh (faces connected through shared vertices) "
        "of which no vertex and no area sample lies within 2% of the input's bounding-box diagonal of an "
        "input point. *Hausdorff*: largest distance from the mesh (every vertex and 1M area-uniform samples) "
        "to the nearest input point. *RMS exact*: for the synthetic inputs, RMS distance to the exact analytic "
        "surface over the 1M mesh samples and the exact input points (two-sided). *Chamfer*: (mean distance "
        "input points → mesh + mean distance mesh samples → nearest input point) / 2. *Chamfer / Open3D*: "
        "Chamfer of the method / Chamfer of Open3D Poisson d8. Distances are divided by the input's "
        "bounding-box diagonal; point-to-mesh distances are exact (Open3D RaycastingScene), nearest points by "
        "k-d tree (scipy).\n"
    )
    d.append("| input | points | method | CPU s | CPU / Open3D | wall s | tri. | self-int. | watertight | manifold | comp. | genus | far pieces | Hausdorff | RMS exact | Chamfer | Chamfer / Open3D |")
    d.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, n, synthetic, facts, results in rows:
        cell = input_cell(name, synthetic, facts)
        ref = results.get(REF, {})
        ref_cpu = ref.get("cpu") if ref.get("ok") else None
        ref_ch = ref.get("chamfer_rel") if ref.get("ok") else None
        for method in METHODS:
            r = results[method]
            if not r["ok"]:
                d.append(f"| {cell} | {n} | {method} | failed | | | | | | | | | | | | | {short(r['error'])} |")
                continue
            cpu_ratio = f"{r['cpu'] / ref_cpu:.2f}" if ref_cpu else "-"
            ch = r.get("chamfer_rel")
            ch_ratio = f"{ch / ref_ch:.2f}" if ch is not None and ref_ch else "-"
            d.append(
                f"| {cell} | {n} | {method} | {r['cpu']:.2f} | {cpu_ratio} | {r['wall']:.1f} | {r['triangles']} | "
                f"{fmt(r.get('self_intersections'), 'd')} | {'yes' if r['watertight'] else 'no'} | "
                f"{'yes' if r['manifold'] else 'no'} | {r.get('components', '-')} | {fmt(r.get('genus'), 'd')} | "
                f"{fmt(r.get('far_pieces'), 'd')} | {fmt(r.get('hausdorff_rel'), '.2e')} | "
                f"{fmt(r.get('rms_exact_rel'), '.2e')} | {fmt(ch, '.2e')} | {ch_ratio} |"
            )
    d.append("")
    d.extend(pictures(a, rows))
    d.append("## Reading the table\n")
    d.extend(summary(rows))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(d) + "\n")


PICTURED = ["bunny", "spot", "fertility", "duck", "torus"]


def pictures(a, rows):
    """Renders the output meshes of a few inputs with `stablesurf render` (240 px, iso view) into
    img/ beside the Markdown file and returns the Markdown of a picture table."""
    img = Path(a.out).parent / "img"
    lines = ["## Pictures\n", "Output meshes rendered by `stablesurf render --size 240` (same iso view for all).\n",
             "| input | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    by_name = {row[0]: row for row in rows}
    any_row = False
    for name in PICTURED:
        if name not in by_name:
            continue
        results = by_name[name][4]
        img.mkdir(parents=True, exist_ok=True)
        cells = []
        for method in METHODS:
            mesh = Path(a.work) / name / MESH_DIRS[method] / "mesh.ply"
            png = img / f"bench-{name}-{MESH_DIRS[method]}.png"
            if results[method]["ok"] and mesh.exists():
                ok, _, _, _ = run_child([a.bin, "render", str(mesh), "-o", str(png), "--size", "240", "-q"], os.environ.copy())
                cells.append(f"![{name} {method}](img/{png.name})" if ok else "render failed")
            else:
                cells.append("failed")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
        any_row = True
    lines.append("")
    return lines if any_row else []


def short(err):
    """The last clause of an error chain, for a table cell."""
    return err.split(": ")[-1][:90].replace("|", "/")


CRITERIA = [
    ("selfint", "0 self-intersecting faces"),
    ("one", "one watertight manifold component"),
    ("genus", "the input's genus (watertight inputs)"),
    ("far", "no piece farther than 2% of the diagonal"),
    ("chamfer", "Chamfer ≤ 1.0× Open3D"),
    ("cpu", "CPU ≤ 0.5× Open3D"),
]


def criteria(facts, results, method):
    """{criterion: (holds, what was measured)} for METHOD on one input; holds is None where the
    criterion does not apply (genus on an input that is not watertight; ratios of the reference)."""
    r, ref = results[method], results[REF]
    if not r["ok"]:
        return {k: (False, f"failed ({short(r['error'])})") for k, _ in CRITERIA}
    out = {}
    n_si = r.get("self_intersections")
    out["selfint"] = (n_si == 0, f"{fmt(n_si, 'd')} self-intersecting faces")
    one = r["watertight"] and r["components"] == 1
    out["one"] = (one, f"{plural(r['components'], 'component')}, {'watertight' if r['watertight'] else 'not watertight'}"
                       f"{'' if r['manifold'] else ', non-manifold'}, {r['boundary_edges']} boundary edges")
    if facts.get("watertight") and facts.get("genus") is not None:
        got = "no genus (not watertight)" if r.get("genus") is None else f"genus {r['genus']}"
        out["genus"] = (r.get("genus") == facts["genus"], f"{got}, input genus {facts['genus']}")
    else:
        out["genus"] = (None, "input not watertight")
    far = r.get("far_pieces")
    out["far"] = (far == 0, f"{fmt(far, 'd')} of {fmt(r.get('pieces'), 'd')} pieces farther than 2% (farthest: "
                            f"{r.get('far_pieces_max_rel', float('nan')):.1%} of the diagonal)")
    if method == REF:
        out["chamfer"] = out["cpu"] = (None, "reference")
    elif not ref["ok"]:
        out["chamfer"] = out["cpu"] = (None, "Open3D failed")
    else:
        ch = r.get("chamfer_rel", float("nan")) / max(ref.get("chamfer_rel", float("nan")), 1e-300)
        out["chamfer"] = (ch <= 1.0, f"Chamfer {ch:.2f}× Open3D ({r.get('chamfer_rel', float('nan')):.2e} vs {ref.get('chamfer_rel', float('nan')):.2e})")
        c = r["cpu"] / max(ref["cpu"], 1e-9)
        out["cpu"] = (c <= 0.5, f"CPU {c:.2f}× Open3D ({r['cpu']:.2f} s vs {ref['cpu']:.2f} s)")
    return {k: (None if h is None else bool(h), t) for k, (h, t) in out.items()}


def span(v):
    lo, hi = f"{min(v):.2f}×", f"{max(v):.2f}×"
    return lo if lo == hi else f"{lo} to {hi}"


def plural(n, word):
    return f"{n} {word}{'' if n == 1 else 's'}"


def summary(rows):
    """Plain statements computed from the table: the acceptance criteria of the default run, per
    criterion and per input, against Open3D Poisson d8."""
    out = []
    ours = "stablesurf default"
    per = [(name, criteria(facts, res, ours), criteria(facts, res, REF)) for name, _, _, facts, res in rows]
    if not per:
        return ["No input ran."]
    out.append(f"**Criteria of the default run** ({plural(len(per), 'input')}; *stablesurf default* against *{REF}*):\n")
    for key, label in CRITERIA:
        mine = [c[key][0] for _, c, _ in per if c[key][0] is not None]
        line = f"- {label}: stablesurf default on {sum(mine)}/{len(mine)} inputs"
        if key not in ("chamfer", "cpu"):
            ref = [c[key][0] for _, _, c in per if c[key][0] is not None]
            line += f", Open3D Poisson d8 on {sum(ref)}/{len(ref)}"
        out.append(line + ".")
    out.append("")
    out.append("**Per input**, the criteria stablesurf default fails:\n")
    for name, c, _ in per:
        failed = [f"{label}: {c[key][1]}" for key, label in CRITERIA if c[key][0] is False]
        out.append(f"- **{name}**: " + ("all hold." if not failed else "; ".join(failed) + "."))
    out.append("")
    glob_ch, glob_cpu = [], []
    for name, _, _, _, res in rows:
        g, ref = res["stablesurf global"], res[REF]
        if g["ok"] and ref["ok"] and "chamfer_rel" in g and "chamfer_rel" in ref:
            glob_ch.append(g["chamfer_rel"] / max(ref["chamfer_rel"], 1e-300))
            glob_cpu.append(g["cpu"] / max(ref["cpu"], 1e-9))
    if glob_ch:
        out.append(
            f"**Global mode** (`--mode global`, one polynomial of degree 8): Chamfer {span(glob_ch)} Open3D's, "
            f"CPU {span(glob_cpu)} Open3D's, on "
            f"{plural(len(glob_ch), 'input')}."
        )
    return out


if __name__ == "__main__":
    main()
