#!/usr/bin/env python3
"""Raw range scans: stablesurf's default run against Open3D Poisson, plain and trimmed.

Called by tools/bench_peers.py (its table's "Raw range scans" section); runs alone as
`tools/validate/.venv/bin/python tools/bench_scans.py --bin BIN --out FILE.md --work DIR`.

Inputs (../shared/data): each single Stanford range scan of `bunny-scans/` (bun000 is the same
file as `../bun000.ply`), and the six registered together through `bunny-scans/bun.conf`.

Per input:
  - oriented points: `stablesurf normals SCAN -o X.ply` (a range grid's triangles face the
    scanner); for bun.conf, each scan's oriented points moved to the common frame as Stanford's
    convention says (p -> R(q)^T p + t, normals rotated alike), concatenated;
  - stablesurf default: `stablesurf run SCAN|bun.conf -o DIR --no-cache -q --formats ply,json`;
  - Open3D Poisson d8 on the same oriented points, raw, and trimmed: vertices whose Poisson
    density is below the 5% quantile removed (the usual recipe for open scans).
Measures (relative to the bounding-box diagonal of the input points): Chamfer = (mean distance
input points -> mesh, exact, + mean distance of 100k area samples of the mesh -> nearest input
point) / 2; "within 1%": the share of the mesh's area (those samples) within 1% of the diagonal
of an input point; for bun.conf also the Chamfer to the zippered bunny (`bunny_zipper.ply`, its
vertices as the points, its diagonal); pymeshlab's components, boundary edges, manifoldness and
self-intersecting faces; CPU (user + sys of the child process).
"""

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import bench_peers as bp  # noqa: E402

SCANS = ["bun000", "bun090", "bun180", "bun270", "bun315", "top2"]
METHODS = ["stablesurf default", "Open3D Poisson d8", "Open3D Poisson d8, trimmed 5%"]
DIRS = {"stablesurf default": "stablesurf", "Open3D Poisson d8": "poisson", "Open3D Poisson d8, trimmed 5%": "poisson-trim"}
PICTURED = ["bun000", "bun.conf"]


def peer(inp, out, trim):
    """Child: Open3D Poisson depth 8 on INP, optionally trimmed at the 5% density quantile."""
    import numpy as np
    import open3d as o3d

    pc = o3d.io.read_point_cloud(inp)
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=8)
    if trim:
        dens = np.asarray(dens)
        mesh.remove_vertices_by_mask(dens < np.quantile(dens, 0.05))
    o3d.io.write_triangle_mesh(out, mesh)


def quat_rotation(qx, qy, qz, qw):
    import numpy as np

    n = (qx * qx + qy * qy + qz * qz + qw * qw) ** 0.5
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def merged_points(conf, oriented, out):
    """The scans of `conf`, oriented (`oriented[name]` PLYs), moved to the common frame."""
    import numpy as np
    import open3d as o3d

    pts, nrm = [], []
    for line in conf.read_text().splitlines():
        f = line.split()
        if not f or f[0] != "bmesh":
            continue
        name = Path(f[1]).stem
        t = np.array([float(v) for v in f[2:5]])
        r = quat_rotation(*[float(v) for v in f[5:9]])
        pc = o3d.io.read_point_cloud(str(oriented[name]))
        pts.append(np.asarray(pc.points) @ r + t)  # rows: R^T p + t
        nrm.append(np.asarray(pc.normals) @ r)
    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.concatenate(pts))
    pc.normals = o3d.utility.Vector3dVector(np.concatenate(nrm))
    o3d.io.write_point_cloud(str(out), pc)


def measure(points, mesh_path, reference=None):
    import numpy as np
    import open3d as o3d
    import pymeshlab
    from scipy.spatial import cKDTree

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(mesh_path))
    res = bp.topology(ms)
    res.pop("genus_any")
    if res["triangles"] == 0:
        return res
    res["self_intersections"] = bp.self_intersections(ms)
    m = ms.current_mesh()
    verts = np.asarray(m.vertex_matrix(), dtype=np.float64)
    tris = np.asarray(m.face_matrix(), dtype=np.int64)
    samples, _ = bp.sample_mesh(verts, tris, 100_000)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tris.astype(np.uint32)))

    def chamfer(pts):
        diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        d_in = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().astype(np.float64)
        d_out, _ = cKDTree(pts).query(samples)
        return 0.5 * (d_in.mean() + d_out.mean()) / diag, float((d_out <= 0.01 * diag).mean())

    res["chamfer_rel"], res["within_1pct"] = chamfer(points)
    if reference is not None:
        res["chamfer_ref_rel"], _ = chamfer(reference)
    return res


def run(bin_path, work):
    """Runs every input and method; returns rows (name, points, results)."""
    import numpy as np
    import open3d as o3d

    data = ROOT.parent / "shared" / "data" / "bunny-scans"
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    if not data.is_dir():
        print(f"bench_scans: {data} not found, raw scans skipped", file=sys.stderr)
        return []
    oriented = {}
    inputs = []  # (name, scan or conf path, oriented points path)
    for s in SCANS:
        src = data / f"{s}.ply"
        dst = work / f"{s}_oriented.ply"
        ok, _, _, err = bp.run_child([bin_path, "normals", str(src), "-o", str(dst), "-q"], os.environ.copy())
        if not ok:
            print(f"bench_scans: normals for {s} failed: {err}", file=sys.stderr)
            continue
        oriented[s] = dst
        inputs.append((s, src, dst))
    conf = data / "bun.conf"
    if len(oriented) == len(SCANS):
        merged = work / "bun.conf_oriented.ply"
        merged_points(conf, oriented, merged)
        inputs.append(("bun.conf", conf, merged))
    zipper = ROOT.parent / "shared" / "data" / "bunny_zipper.ply"
    reference = np.asarray(o3d.io.read_triangle_mesh(str(zipper)).vertices) if zipper.exists() else None
    rows = []
    for name, src, pts_path in inputs:
        pts = bp.read_points(pts_path)
        results = {}
        for method in METHODS:
            out_dir = work / name / DIRS[method]
            out_dir.mkdir(parents=True, exist_ok=True)
            mesh = out_dir / "mesh.ply"
            if method == "stablesurf default":
                cmd = [bin_path, "run", str(src), "-o", str(out_dir), "--no-cache", "-q", "--formats", "ply,json"]
                env = os.environ.copy()
            else:
                cmd = [sys.executable, str(Path(__file__).resolve()), "--peer", str(pts_path), str(mesh),
                       "trim" if "trimmed" in method else "plain"]
                env = dict(os.environ, OMP_WAIT_POLICY="passive")
            ok, cpu, wall, err = bp.run_child(cmd, env)
            r = {"ok": ok and mesh.exists(), "cpu": cpu, "wall": wall, "error": err}
            if r["ok"]:
                try:
                    r.update(measure(pts, mesh, reference if name == "bun.conf" else None))
                except Exception as e:  # a mesh the measuring tools cannot read
                    r["ok"], r["error"] = False, f"measure: {e}"
            results[method] = r
            print(f"bench_scans: {name:9s} {method:30s} {'ok' if r['ok'] else 'FAILED ' + r['error']}", file=sys.stderr)
        rows.append((name, len(pts), results))
    return rows


def section(bin_path, rows, out, work):
    """The Markdown of the raw-scan section, pictures rendered into img/ beside `out`."""
    d = ["## Raw range scans\n"]
    d.append(
        "Generated by `tools/bench_scans.py` (called by `tools/bench_peers`). Inputs: the six Stanford bunny "
        "range scans of `../shared/data/bunny-scans/` one by one, and all six through `bun.conf`. Every method gets "
        "the same oriented points: `stablesurf normals SCAN` (each range grid's triangles face its scanner), moved "
        "to the common frame for `bun.conf`. *stablesurf default* is `stablesurf run SCAN|bun.conf` (detail mode, "
        "support trimming on); *Open3D* is Poisson depth 8, raw and trimmed at the 5% density quantile. *Chamfer*: "
        "(mean distance input points → mesh + mean distance of 100k area samples → nearest input point) / 2, over "
        "the input's diagonal; *within 1%*: share of the mesh area within 1% of the diagonal of an input point; "
        "*Chamfer to zipper*: the same against the vertices of `bunny_zipper.ply` (Stanford's zippered "
        "reconstruction), over its diagonal. Topology and self-intersecting faces by pymeshlab.\n"
    )
    d.append("| input | points | method | CPU s | tri. | comp. | boundary edges | manifold | self-int. | within 1% | Chamfer | Chamfer to zipper |")
    d.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, n, results in rows:
        for method in METHODS:
            r = results[method]
            if not r["ok"]:
                d.append(f"| {name} | {n} | {method} | failed | | | | | | | | {bp.short(r['error'])} |")
                continue
            d.append(
                f"| {name} | {n} | {method} | {r['cpu']:.2f} | {r['triangles']} | {r['components']} | "
                f"{r['boundary_edges']} | {'yes' if r['manifold'] else 'no'} | {r.get('self_intersections', '-')} | "
                f"{100 * r.get('within_1pct', float('nan')):.2f}% | {bp.fmt(r.get('chamfer_rel'), '.2e')} | "
                f"{bp.fmt(r.get('chamfer_ref_rel'), '.2e')} |"
            )
    d.append("")
    img = Path(out).parent / "img"
    img.mkdir(parents=True, exist_ok=True)
    d.append("Pictures (`stablesurf render --size 240`, iso view, y up):\n")
    d.append("| input | " + " | ".join(METHODS) + " |")
    d.append("|---|" + "---|" * len(METHODS))
    for name, _, results in rows:
        if name not in PICTURED:
            continue
        cells = []
        for method in METHODS:
            mesh = Path(work) / name / DIRS[method] / "mesh.ply"
            png = img / f"scan-{name.replace('.', '-')}-{DIRS[method]}.png"
            ok = False
            if results[method]["ok"] and mesh.exists():
                ok, _, _, _ = bp.run_child([bin_path, "render", str(mesh), "-o", str(png), "--size", "240", "-q"], os.environ.copy())
            cells.append(f"![{name} {method}](img/{png.name})" if ok else "failed")
        d.append(f"| {name} | " + " | ".join(cells) + " |")
    d.append("")
    # Plain statements from the rows.
    for name, _, results in rows:
        ours, trimmed = results["stablesurf default"], results["Open3D Poisson d8, trimmed 5%"]
        if not (ours["ok"] and trimmed["ok"]):
            continue
        key = "chamfer_ref_rel" if name == "bun.conf" else "chamfer_rel"
        plain = results["Open3D Poisson d8"]
        ref = min((r.get(key, float("inf")) for r in (plain, trimmed) if r["ok"]), default=float("nan"))
        d.append(
            f"- **{name}**: stablesurf {ours[key]:.2e} against Poisson's best {ref:.2e} "
            f"({'at or below' if ours[key] <= ref else 'above'}; {'Chamfer to the zipper' if name == 'bun.conf' else 'Chamfer'}), "
            f"{100 * ours['within_1pct']:.2f}% of its area within 1% of the data (trimmed Poisson {100 * trimmed['within_1pct']:.2f}%), "
            f"{ours['components']} component(s), {'manifold' if ours['manifold'] else 'not manifold'}, "
            f"{ours.get('self_intersections', '-')} self-intersecting faces."
        )
    d.append("")
    return d


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin")
    ap.add_argument("--out")
    ap.add_argument("--work")
    ap.add_argument("--peer", nargs=3, metavar=("IN", "OUT", "TRIM"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.peer:
        peer(a.peer[0], a.peer[1], a.peer[2] == "trim")
        return
    if not (a.bin and a.out and a.work):
        ap.error("--bin, --out and --work are required")
    rows = run(a.bin, a.work)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(section(a.bin, rows, a.out, a.work)) + "\n")
    print(a.out)


if __name__ == "__main__":
    main()
