#!/usr/bin/env python3
"""stablesurf against Poisson surface reconstruction, side by side in one run.

Run through the wrapper `tools/bench_peers [--quick]` (it builds the release binary and the
synthetic inputs, then calls this script in tools/validate/.venv).

Per input (synthetic shapes with exact normals, the bunny, the duck, a 1M-point torus), four
reconstructions, each in its own child process:
  - stablesurf global:  stablesurf run INPUT -o DIR --no-cache -q --formats ply,json --mode global
  - stablesurf detail:  the same with --mode detail (recorded as "failed" while it does not exist)
  - Open3D:             TriangleMesh.create_from_point_cloud_poisson(depth=8), raw output
  - pymeshlab:          generate_surface_reconstruction_screened_poisson(depth=8), raw output
The peers run with OMP_WAIT_POLICY=passive. Every input file carries oriented normals, so every
method gets the same points and normals (the bunny and duck normals come from
`stablesurf normals`, the pipeline's automatic source).

Measures (one tool for all):
  - CPU seconds: user + sys of the child process (resource.getrusage(RUSAGE_CHILDREN) deltas),
    whole process (start-up, reading, writing included); ratio = peer CPU / stablesurf global CPU.
  - triangles, watertight and manifold: pymeshlab get_topological_measures on the written mesh
    (manifold: no non-manifold edge or vertex; watertight: manifold and no boundary edge).
  - accuracy, relative to the input's bounding-box diagonal:
      synthetic inputs: RMS distance to the exact analytic surface, two-sided: 100k points sampled
        uniformly on the mesh -> exact surface (closed form for sphere, torus and cube; Newton
        projection onto f = 0 otherwise, capped by the distance to the nearest exact sample),
        plus the exact input points -> mesh; one RMS over both sets.
      every input: symmetric Chamfer distance = (mean distance input points -> mesh + mean
        distance of 100k mesh samples -> nearest input point) / 2.
    Point-to-mesh distances are exact (Open3D RaycastingScene); nearest points by k-d tree.
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
METHODS = ["stablesurf global", "stablesurf detail", "Open3D Poisson d8", "pymeshlab screened Poisson d8"]
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

def measure(name, input_points, tree, mesh_path, synthetic):
    import numpy as np
    import open3d as o3d
    import pymeshlab
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(mesh_path))
    topo = ms.get_topological_measures()
    faces = int(topo["faces_number"])
    manifold = bool(topo["is_mesh_two_manifold"]) and topo["non_two_manifold_edges"] == 0 and topo["non_two_manifold_vertices"] == 0
    watertight = manifold and topo["boundary_edges"] == 0 and faces > 0
    res = {
        "triangles": faces,
        "watertight": watertight,
        "manifold": manifold,
        "components": int(topo["connected_components_number"]),
        "boundary_edges": int(topo["boundary_edges"]),
    }
    if faces == 0:
        return res
    m = ms.current_mesh()
    verts = np.asarray(m.vertex_matrix(), dtype=np.float64)
    tris = np.asarray(m.face_matrix(), dtype=np.int64)
    samples = sample_mesh(verts, tris, 100_000)
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
    if synthetic:
        d_exact = exact_distance(name, samples, tree)
        both = np.concatenate([d_exact, d_in])
        res["rms_exact_rel"] = float(np.sqrt((both * both).mean()) / diag)
    return res


def sample_mesh(verts, tris, n):
    """n points uniformly distributed by area on the mesh (fixed seed)."""
    import numpy as np

    a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    rng = np.random.default_rng(2008)
    t = rng.choice(len(tris), size=n, p=area / area.sum())
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    return (1 - r1) * a[t] + r1 * (1 - r2) * b[t] + r1 * r2 * c[t]


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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--inputs", help="directory with the synthetic input PLYs")
    ap.add_argument("--bin", help="the stablesurf binary")
    ap.add_argument("--out", help="the Markdown file to write")
    ap.add_argument("--work", help="scratch directory for outputs")
    ap.add_argument("--peer", nargs=3, metavar=("WHICH", "IN", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.peer:
        peer_main(*a.peer)
        return
    if not (a.inputs and a.bin and a.out and a.work):
        ap.error("--inputs, --bin, --out and --work are required")
    import numpy as np  # noqa: F401

    start = time.perf_counter()
    work = Path(a.work)
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    data = ROOT.parent / "shared" / "data"
    inputs = []  # (name, path, synthetic)
    shapes = ["torus"] if a.quick else SYNTHETIC
    for s in shapes:
        inputs.append((s, Path(a.inputs) / f"{s}.ply", True))
    if not a.quick:
        for name, file in [("bunny", "bunny_zipper.ply"), ("duck", "duck.ply")]:
            src = data / file
            if not src.exists():
                print(f"bench_peers: {src} not found, skipped", file=sys.stderr)
                continue
            dst = work / f"{name}_oriented.ply"
            ok, _, _, err = run_child([a.bin, "normals", str(src), "-o", str(dst), "-q"], os.environ.copy())
            if ok:
                inputs.append((name, dst, False))
            else:
                print(f"bench_peers: normals for {name} failed: {err}", file=sys.stderr)
        big = Path(a.inputs) / "torus_1m.ply"
        if big.exists():
            inputs.append(("torus_1m", big, True))

    ours_env = os.environ.copy()
    peer_env = dict(os.environ, OMP_WAIT_POLICY="passive")
    baseline = python_baseline(peer_env)
    rows = []
    for name, path, synthetic in inputs:
        from scipy.spatial import cKDTree

        pts = read_points(path)
        tree = cKDTree(pts)
        results = {}
        for method in METHODS:
            if method.startswith("stablesurf"):
                mode = method.split()[1]
                out_dir = work / name / f"stablesurf-{mode}"
                cmd = [a.bin, "run", str(path), "-o", str(out_dir), "--no-cache", "-q", "--formats", "ply,json",
                       "--mode", mode]
                mesh = out_dir / "mesh.ply"
                env = ours_env
            else:
                which = "open3d" if method.startswith("Open3D") else "pymeshlab"
                out_dir = work / name / which
                out_dir.mkdir(parents=True, exist_ok=True)
                mesh = out_dir / "mesh.ply"
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
        rows.append((name, len(pts), synthetic, results))
    total = time.perf_counter() - start
    write_doc(a, rows, baseline, total)
    (Path(a.out).with_suffix(".json")).write_text(json.dumps({"rows": rows, "baseline": baseline, "total_wall_s": total}, indent=1, default=str))
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


def write_doc(a, rows, baseline, total):
    d = []
    d.append("# stablesurf against Poisson reconstruction\n")
    d.append(
        f"Generated by `tools/bench_peers{' --quick' if a.quick else ''}` on "
        f"{datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, total {total:.0f} s wall. "
        f"Machine: {machine()}. Peers: {versions()}. Do not edit by hand; regenerate with "
        "`bash tools/bench_peers_install.sh && tools/bench_peers` (the install step sets up Open3D, pymeshlab "
        "and scipy in tools/validate/.venv).\n"
    )
    d.append(
        "**What runs.** Every input file carries oriented normals, so all methods get the same points and "
        "normals: the synthetic shapes (20,000 points, and a 1,000,000-point torus) have exact normals; the "
        "bunny and the duck carry the normals `stablesurf normals` computes. *stablesurf global* is "
        "`stablesurf run INPUT -o DIR --no-cache -q --formats ply,json --mode global` (one degree-8 polynomial, automatic "
        "κ, octree depth 8, and its own accuracy report); *stablesurf detail* adds `--mode detail`. "
        "*Open3D* is `create_from_point_cloud_poisson(depth=8)`, *pymeshlab* is "
        "`generate_surface_reconstruction_screened_poisson(depth=8)`, both raw (no density trimming), "
        "with `OMP_WAIT_POLICY=passive`.\n"
    )
    d.append(
        "**Measures.** *CPU s*: user + sys of the child process (getrusage RUSAGE_CHILDREN), whole process; "
        f"for the peers it includes Python start-up and the library import (measured alone: Open3D "
        f"{baseline.get('open3d', float('nan')):.2f} s, pymeshlab {baseline.get('pymeshlab', float('nan')):.2f} s). "
        "*ratio*: CPU of the method / CPU of stablesurf global (above 1: slower than ours). *tri.*: output "
        "triangles. *watertight* / *manifold*: pymeshlab's topological measures on every output mesh (manifold: "
        "no non-manifold edge or vertex; watertight: manifold without boundary edges). *RMS exact*: for the "
        "synthetic inputs, RMS distance to the exact analytic surface over 100k uniform mesh samples and the "
        "exact input points (two-sided), divided by the input's bounding-box diagonal. *Chamfer*: symmetric "
        "Chamfer distance = (mean distance input points → mesh + mean distance mesh samples → nearest input "
        "point) / 2, divided by the bounding-box diagonal. Point-to-mesh distances are exact (Open3D "
        "RaycastingScene).\n"
    )
    d.append("| input | points | method | CPU s | ratio | wall s | tri. | watertight | manifold | comp. | RMS exact | Chamfer |")
    d.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, n, synthetic, results in rows:
        ours = results.get("stablesurf global", {})
        ours_cpu = ours.get("cpu") if ours.get("ok") else None
        for method in METHODS:
            r = results[method]
            if not r["ok"]:
                d.append(f"| {name} | {n} | {method} | failed | | | | | | | | {short(r['error'])} |")
                continue
            ratio = f"{r['cpu'] / ours_cpu:.2f}" if ours_cpu else "-"
            rms = f"{r['rms_exact_rel']:.2e}" if "rms_exact_rel" in r else "-"
            ch = f"{r['chamfer_rel']:.2e}" if "chamfer_rel" in r else "-"
            d.append(
                f"| {name} | {n} | {method} | {r['cpu']:.2f} | {ratio} | {r['wall']:.1f} | {r['triangles']} | "
                f"{'yes' if r['watertight'] else 'no'} | {'yes' if r['manifold'] else 'no'} | {r.get('components', '-')} | {rms} | {ch} |"
            )
    d.append("")
    d.extend(pictures(a, rows))
    d.append("## Reading the table\n")
    d.extend(summary(rows))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(d) + "\n")


PICTURED = ["bunny", "duck", "cube", "heart", "torus"]
MESH_DIRS = {"stablesurf global": "stablesurf-global", "stablesurf detail": "stablesurf-detail",
             "Open3D Poisson d8": "open3d", "pymeshlab screened Poisson d8": "pymeshlab"}


def pictures(a, rows):
    """Renders the output meshes of a few inputs with `stablesurf render` (240 px, iso view) into
    img/ beside the Markdown file and returns the Markdown of a picture table."""
    img = Path(a.out).parent / "img"
    img.mkdir(parents=True, exist_ok=True)
    lines = ["## Pictures\n", "Output meshes rendered by `stablesurf render --size 240` (same iso view for all).\n",
             "| input | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
    any_row = False
    for name, _, _, results in rows:
        if name not in PICTURED:
            continue
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


def summary(rows):
    """Plain statements computed from the table: where stablesurf wins and where it loses."""
    out = []
    acc, cpu, tri, tight = [], [], [], []
    for name, n, synthetic, results in rows:
        ours = results["stablesurf global"]
        key = "rms_exact_rel" if synthetic else "chamfer_rel"
        for m in METHODS[2:]:
            r = results[m]
            if ours["ok"] and r["ok"] and key in ours and key in r:
                acc.append(ours[key] / max(r[key], 1e-300))
                cpu.append(r["cpu"] / max(ours["cpu"], 1e-9))
                tri.append(ours["triangles"] / max(r["triangles"], 1))
                tight.append(r["watertight"])
    if acc:
        ours_tight = sum(1 for _, _, _, res in rows if res["stablesurf global"].get("watertight"))
        ours_ok = sum(1 for _, _, _, res in rows if res["stablesurf global"]["ok"])
        out.append(
            f"**In short.** Against Poisson at depth 8, stablesurf global's error (RMS to the exact surface, or Chamfer "
            f"on the scans) is {min(acc):.1f}× to {max(acc):.1f}× the peer's: one polynomial of degree 8 is a coarse, "
            f"smooth model{', and it loses on accuracy on every input' if min(acc) > 1.1 else ''}. "
            f"The peers' CPU is {min(cpu):.2f}× to {max(cpu):.2f}× ours (above 1: ours is cheaper). stablesurf writes "
            f"{min(tri):.0f}× to {max(tri):.0f}× more triangles at its default depth 8. stablesurf's mesh is watertight "
            f"on {ours_tight}/{ours_ok} inputs, the peers' on {sum(tight)}/{len(tight)} runs.\n"
        )
    for name, n, synthetic, results in rows:
        ours = results["stablesurf global"]
        peers = [m for m in METHODS[2:] if results[m]["ok"]]
        if not ours["ok"] or not peers:
            continue
        key = "rms_exact_rel" if synthetic else "chamfer_rel"
        label = "RMS to the exact surface" if synthetic else "Chamfer distance"
        best = min(peers, key=lambda m: results[m].get(key, float("inf")))
        b = results[best]
        acc = ours.get(key, float("nan")) / max(b.get(key, float("nan")), 1e-300)
        speed = b["cpu"] / max(ours["cpu"], 1e-9)
        verdict = "less accurate" if acc > 1.1 else ("as accurate" if acc > 0.9 else "more accurate")
        out.append(
            f"- **{name}** ({n} points): stablesurf global is {verdict} than the best peer ({best}): {label} "
            f"{ours.get(key, float('nan')):.2e} vs {b.get(key, float('nan')):.2e} ({acc:.1f}×), using "
            f"{ours['cpu']:.1f} s CPU against {b['cpu']:.1f} s ({'faster' if speed > 1 else 'slower'}, {max(speed, 1 / max(speed, 1e-9)):.1f}×); "
            f"{ours['triangles']} vs {b['triangles']} triangles; watertight {'yes' if ours['watertight'] else 'no'} vs "
            f"{'yes' if b['watertight'] else 'no'}."
        )
    det = [r for _, _, _, res in rows for r in [res["stablesurf detail"]]]
    if det and not any(r["ok"] for r in det):
        out.append(f"- *stablesurf detail* failed on every input (`{short(det[0]['error'])}`): the mode is not in this build yet.")
    return out


if __name__ == "__main__":
    main()
