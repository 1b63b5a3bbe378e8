#!/usr/bin/env python3
"""stablesurf against Open3D on noisy, unoriented points, every mesh scored against the clean source.

Run through the wrapper `tools/bench_noise [--quick] [--bin PATH] ...` (it builds the release binary
unless --bin names one, then calls this script in tools/validate/.venv). It answers the acceptance
criteria of the default `run` on noisy data; the ground truth is the clean source mesh, never the
noisy points.

Inputs, written once under target/bench-noise/inputs (file names keyed by model, sigma and seed)
and reused:
  - noise levels: each mesh of ../shared/data named in MODELS (loaded by pymeshlab; its
    watertightness, genus and Euler characteristic V - E + F are the truth; genus "n/a" when the
    source is not watertight). 60,000 points drawn area-uniformly on it (numpy Generator seeded
    with SEED and the model), isotropic Gaussian noise of sigma = 0, 0.25%, 0.5%, 1% of the
    source's bounding-box diagonal added (its own seeded stream, the same sample positions at every
    sigma); written as binary little-endian PLY with x y z only, and a second file with the same
    points and the exact (outward) normal of the sampled triangle as nx ny nz.
  - simulated scans of CAD parts: fandisk.obj, and a block with a cylindrical through-hole (genus 1,
    made here with numpy). A range scanner simulated with Open3D's RaycastingScene: pinhole views
    from the upper hemisphere only (SCAN_VIEWS; the underside is never seen), a SCAN_RES x SCAN_RES
    grid of rays per view, hits kept, the views merged and SCAN_POINTS of the hits drawn at random;
    Gaussian noise added along each ray, scaled so that the median distance of the noisy points to
    the surface is SCAN_MEDIAN of the diagonal. The truth file holds the hit triangles' normals.

Methods, each in its own child process, CPU = user + sys of the child (getrusage RUSAGE_CHILDREN
deltas, whole process), timeout bench_peers.TIMEOUT s (a failure row):
  - stablesurf default: BIN run INPUT -o DIR --no-cache -q --formats ply,json -> DIR/mesh.ply; its
    noise estimate is report.json's noise.sigma_per_diagonal when present.
  - Open3D pipeline (the reference of the ratios): estimate_normals(KDTreeSearchParamKNN(30)),
    orient_normals_consistent_tangent_plane(30), create_from_point_cloud_poisson(depth=8), vertices
    whose density is below the 1% quantile removed.
  - Poisson, true normals: the same Poisson and trim on the file with the exact normals.
The Open3D children run with OMP_WAIT_POLICY=passive, as in tools/bench_peers.

Measures of each output mesh against the clean source (both shifted by the source's box centre;
distances divided by the source's bounding-box diagonal), from N_SAMPLES area-uniform samples of
each mesh (seed MEASURE_SEED) and exact point-to-triangle closest points (RaycastingScene
compute_closest_points):
  - Chamfer: (mean distance output samples -> source + mean distance source samples -> output) / 2.
  - normal consistency: mean over both sample sets of |n . n'|, n the normal of the triangle a
    sample lies on, n' the normal of the closest triangle of the other mesh (1 = parallel; sign
    ignored, so a flipped mesh is not penalised).
  - F-score at TAU of the diagonal: 2PR / (P + R), P the share of output samples within TAU of
    the source, R the share of source samples within TAU of the output.
  - Hausdorff: the larger of the two largest sample distances.
  - components: pieces of faces connected through shared vertices; watertight and genus from
    pymeshlab's get_topological_measures (genus of watertight meshes only); Euler characteristic
    V - E + F over the vertices faces use; self-intersecting faces as MeshLab selects them
    (bench_peers.self_intersections); triangles.
The summary states, per acceptance criterion, on how many inputs stablesurf default meets it.
"""

import argparse
import datetime
import json
import math
import os
import shutil
import subprocess
import sys
import time
import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import bench_peers as bp  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
MODELS = [("spot", "spot.obj"), ("fertility", "fertility.ply"), ("max_planck", "max_planck.obj"),
          ("patella_vhf_left", "patella_vhf_left.ply"), ("quadknot", "quadknot.obj"),
          ("fandisk", "fandisk.obj"), ("duck", "duck.ply"), ("teapot", "teapot.obj"),
          ("bunny_zipper", "bunny_zipper.ply")]
SIGMAS = [0.0, 0.25, 0.5, 1.0]  # % of the source's bounding-box diagonal
QUICK = ("spot", 0.5)
SCAN_SOURCES = ["fandisk", "holed_block"]
SEED = 2026  # input sampling, noise, scanner
MEASURE_SEED = 2008  # area samples of the meshes that are scored
N_POINTS = 60_000
N_SAMPLES = 200_000
TAU = 0.005  # F-score threshold, share of the diagonal
SCAN_VIEWS = [(0, 30), (120, 30), (240, 30), (60, 75)]  # (azimuth, elevation) in degrees, z up
SCAN_RES = 300
SCAN_POINTS = 60_000
SCAN_MEDIAN = 0.005
OURS, REF, TRUE = "stablesurf default", "Open3D pipeline", "Poisson, true normals"
METHODS = [OURS, REF, TRUE]
DIRS = {OURS: "stablesurf", REF: "open3d", TRUE: "poisson-true-normals"}
BEGIN, END = "<!-- bench_noise:begin -->", "<!-- bench_noise:end -->"


def log(msg):
    print(f"bench_noise: {msg}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------- peers (run in a child process)

def peer_main(which, inp, out):
    """Child: Open3D Poisson depth 8 on INP (normals estimated and oriented first for 'pipeline',
    read from the file for 'true'), vertices under the 1% density quantile removed; writes OUT."""
    import numpy as np
    import open3d as o3d

    pc = o3d.io.read_point_cloud(inp)
    if which == "pipeline":
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
        pc.orient_normals_consistent_tangent_plane(30)
    elif which != "true" or not pc.has_normals():
        raise SystemExit(f"bad peer {which} or input without normals")
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=8)
    dens = np.asarray(dens)
    mesh.remove_vertices_by_mask(dens < np.quantile(dens, 0.01))
    o3d.io.write_triangle_mesh(out, mesh)


# ---------------------------------------------------------------- meshes

def face_normals(v, t):
    """Unit normal of every triangle (zero for a degenerate one)."""
    import numpy as np

    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


def area_samples(v, t, n, rng):
    """n points uniformly distributed by area on the mesh, and the triangle of each."""
    import numpy as np

    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    f = rng.choice(len(t), size=n, p=area / area.sum())
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    return (1 - r1) * a[f] + r1 * (1 - r2) * b[f] + r1 * r2 * c[f], f


def euler(t):
    """V - E + F over the vertices the faces use."""
    import numpy as np

    edges = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    return len(np.unique(t)) - len(np.unique(edges, axis=0)) + len(t)


def components(v, t):
    import numpy as np

    return len(np.unique(bp.face_components(len(v), t)))


def scene_of(v, t):
    import numpy as np
    import open3d as o3d

    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(t.astype(np.uint32)))
    return s


def closest(scene, fn, q, qn):
    """Distance from points q to the scene's mesh, and |qn . normal of the closest triangle|."""
    import numpy as np
    import open3d as o3d

    r = scene.compute_closest_points(o3d.core.Tensor(q.astype(np.float32)))
    d = np.linalg.norm(r["points"].numpy().astype(np.float64) - q, axis=1)
    return d, np.abs((qn * fn[r["primitive_ids"].numpy()]).sum(axis=1))


def read_mesh(path):
    """pymeshlab MeshSet of the file, its vertices (float64) and triangles (int64)."""
    import numpy as np
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    m = ms.current_mesh()
    return ms, np.asarray(m.vertex_matrix(), dtype=np.float64), np.asarray(m.face_matrix(), dtype=np.int64)


class Source:
    """A clean mesh: the truth of its inputs and what every output is scored against."""

    def __init__(self, name, path):
        import numpy as np

        ms, v, t = read_mesh(path)
        topo = bp.topology(ms)
        self.name, self.file, self.v, self.t = name, path.name, v, t
        used = v[np.unique(t)]
        lo, hi = used.min(axis=0), used.max(axis=0)
        self.center, self.diag = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
        self.truth = {"watertight": topo["watertight"], "genus": topo["genus"], "euler": euler(t),
                      "components": components(v, t), "boundary_edges": topo["boundary_edges"]}
        vc = v - self.center
        self.fn = face_normals(vc, t)
        a, b, c = vc[t[:, 0]], vc[t[:, 1]], vc[t[:, 2]]
        if (a * np.cross(b, c)).sum() < 0:  # inward winding: the exact normals point outward
            self.fn = -self.fn
        self.scene = scene_of(vc, t)
        self.samples, f = area_samples(vc, t, N_SAMPLES, np.random.default_rng(MEASURE_SEED))
        self.sample_normals = self.fn[f]

    def truth_text(self):
        tr = self.truth
        if tr["watertight"]:
            return f"genus {tr['genus']}, χ {tr['euler']}"
        return f"not watertight: {tr['boundary_edges']} boundary edges, genus n/a"


def holed_block(path, n=64, a=1.0, h=0.35, r=0.45):
    """Writes a 2a x 2a x 2h block with a cylindrical through-hole of radius r along z (genus 1,
    watertight, outward winding) as a PLY mesh: rings of n vertices on the hole and on the square
    outline (the square's points on the rays of the hole's, n a multiple of 8 so the corners are
    vertices), joined on the top and bottom faces, the outer walls and the hole's wall."""
    import numpy as np
    import open3d as o3d

    ang = 2 * np.pi * np.arange(n) / n
    c, s = np.cos(ang), np.sin(ang)
    k = a / np.maximum(np.abs(c), np.abs(s))
    rings = []  # hole top, square top, hole bottom, square bottom
    for z in (h, -h):
        rings += [np.c_[r * c, r * s, np.full(n, z)], np.c_[k * c, k * s, np.full(n, z)]]
    v = np.concatenate(rings)
    i = np.arange(n)
    j = (i + 1) % n
    ht, st, hb, sb = i, n + i, 2 * n + i, 3 * n + i
    ht1, st1, hb1, sb1 = j, n + j, 2 * n + j, 3 * n + j
    t = np.concatenate([
        np.c_[ht, st, st1], np.c_[ht, st1, ht1],  # top, +z
        np.c_[hb, sb1, sb], np.c_[hb, hb1, sb1],  # bottom, -z
        np.c_[sb, sb1, st1], np.c_[sb, st1, st],  # outer walls, outward
        np.c_[hb, ht1, hb1], np.c_[hb, ht, ht1],  # hole's wall, towards the axis
    ])
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    o3d.io.write_triangle_mesh(str(path), mesh)


# ---------------------------------------------------------------- inputs

def write_ply(path, p, n=None):
    """Binary little-endian PLY, float x y z (and nx ny nz), written atomically."""
    import numpy as np

    props = ["x", "y", "z"] + ([] if n is None else ["nx", "ny", "nz"])
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(p)}\n"
    head += "".join(f"property float {q}\n" for q in props) + "end_header\n"
    data = p if n is None else np.hstack([p, n])
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as f:
        f.write(head.encode("ascii"))
        f.write(np.ascontiguousarray(data, dtype="<f4").tobytes())
    tmp.replace(path)


def noisy_input(src, sigma, folder):
    """(points file, file with the exact normals) of SRC at noise SIGMA (% of the diagonal)."""
    import numpy as np

    key = f"{src.name}_sigma{sigma:g}_seed{SEED}"
    pts, nrm = folder / f"{key}.ply", folder / f"{key}_normals.ply"
    if pts.exists() and nrm.exists():
        return pts, nrm
    model = zlib.crc32(src.name.encode())
    p, f = area_samples(src.v, src.t, N_POINTS, np.random.default_rng([SEED, model]))
    p = p + np.random.default_rng([SEED, model, round(sigma * 1000)]).normal(0, sigma / 100 * src.diag, p.shape)
    write_ply(nrm, p, src.fn[f])
    write_ply(pts, p)
    return pts, nrm


def scan_input(src, folder):
    """(points file, normals file, facts) of a simulated partial range scan of SRC."""
    import numpy as np
    import open3d as o3d
    from scipy.spatial import cKDTree

    key = f"scan_{src.name}_seed{SEED}"
    pts, nrm, facts_file = folder / f"{key}.ply", folder / f"{key}_normals.ply", folder / f"{key}.json"
    if pts.exists() and nrm.exists() and facts_file.exists():
        return pts, nrm, json.loads(facts_file.read_text())
    dist = 1.5 * src.diag  # eyes on a sphere around the box centre; the field of view holds the box
    fov = 2 * math.degrees(math.asin(0.5 / 1.5)) + 4
    origin, direction, t_hit, prim = [], [], [], []
    for az, el in SCAN_VIEWS:
        az, el = math.radians(az), math.radians(el)
        eye = dist * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            fov_deg=fov, center=[0, 0, 0], eye=eye.tolist(), up=[0, 0, 1], width_px=SCAN_RES, height_px=SCAN_RES)
        rays = rays.numpy().reshape(-1, 6).astype(np.float64)
        rays[:, 3:] /= np.linalg.norm(rays[:, 3:], axis=1, keepdims=True)
        hit = src.scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
        th = hit["t_hit"].numpy()
        keep = np.isfinite(th)
        origin.append(rays[keep, :3])
        direction.append(rays[keep, 3:])
        t_hit.append(th[keep].astype(np.float64))
        prim.append(hit["primitive_ids"].numpy()[keep])
    origin, direction, t_hit, prim = (np.concatenate(x) for x in (origin, direction, t_hit, prim))
    hits = len(t_hit)
    rng = np.random.default_rng([SEED, zlib.crc32(src.name.encode())])
    pick = rng.choice(hits, size=min(SCAN_POINTS, hits), replace=False)
    origin, direction, t_hit, prim = origin[pick], direction[pick], t_hit[pick], prim[pick]
    z = rng.standard_normal(len(t_hit))
    cos = np.abs((direction * src.fn[prim]).sum(axis=1))
    target = SCAN_MEDIAN * src.diag
    s = target / np.median(np.abs(z) * cos)  # first guess from the local planes, then one correction

    def noisy(s):
        p = origin + direction * (t_hit + s * z)[:, None]
        return p, src.scene.compute_distance(o3d.core.Tensor(p.astype(np.float32))).numpy().astype(np.float64)

    p, d = noisy(s)
    s *= target / np.median(d)
    p, d = noisy(s)
    clean = origin + direction * t_hit[:, None]
    seen, _ = cKDTree(clean).query(src.samples)
    facts = {"views": len(SCAN_VIEWS), "hits": int(hits), "points": len(p), "ray_sigma_rel": float(s) / src.diag,
             "median_rel": float(np.median(d)) / src.diag, "rms_rel": float(np.sqrt((d * d).mean())) / src.diag,
             "seen_share": float((seen <= 0.01 * src.diag).mean())}
    write_ply(nrm, p + src.center, src.fn[prim])
    write_ply(pts, p + src.center)
    facts_file.write_text(json.dumps(facts, indent=1))
    return pts, nrm, facts


# ---------------------------------------------------------------- measuring

def measure(src, mesh_path):
    """The scores of one output mesh against the clean source (see the module's docstring)."""
    import numpy as np

    ms, v, t = read_mesh(mesh_path)
    topo = bp.topology(ms)
    res = {"triangles": topo["triangles"], "watertight": topo["watertight"], "genus": topo["genus"],
           "boundary_edges": topo["boundary_edges"]}
    if len(t) == 0:
        return res
    res["self_intersections"] = bp.self_intersections(ms)
    res["components"] = components(v, t)
    res["euler"] = euler(t)
    v = v - src.center
    fn = face_normals(v, t)
    samples, f = area_samples(v, t, N_SAMPLES, np.random.default_rng(MEASURE_SEED))
    d_out, nc_out = closest(src.scene, src.fn, samples, fn[f])
    d_src, nc_src = closest(scene_of(v, t), fn, src.samples, src.sample_normals)
    tau = TAU * src.diag
    precision, recall = float((d_out <= tau).mean()), float((d_src <= tau).mean())
    res.update({
        "chamfer_rel": 0.5 * (d_out.mean() + d_src.mean()) / src.diag,
        "normal_consistency": float(np.concatenate([nc_out, nc_src]).mean()),
        "precision": precision, "recall": recall,
        "fscore": 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0,
        "hausdorff_rel": float(max(d_out.max(), d_src.max())) / src.diag,
    })
    return res


def noise_figure(report):
    """report.json's noise.sigma_per_diagonal, or None."""
    try:
        value = json.loads(Path(report).read_text())["noise"]["sigma_per_diagonal"]
        return float(value) if value is not None else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def run_methods(a, src, pts, nrm, work):
    """{method: result} for the three methods on one input."""
    results = {}
    for method in METHODS:
        out_dir = work / DIRS[method]
        shutil.rmtree(out_dir, ignore_errors=True)
        mesh = out_dir / "mesh.ply"
        if method == OURS:
            cmd = [a.bin, "run", str(pts), "-o", str(out_dir), "--no-cache", "-q", "--formats", "ply,json"]
            env = os.environ.copy()
        else:
            out_dir.mkdir(parents=True)
            which, inp = ("pipeline", pts) if method == REF else ("true", nrm)
            cmd = [sys.executable, str(Path(__file__).resolve()), "--peer", which, str(inp), str(mesh)]
            env = dict(os.environ, OMP_WAIT_POLICY="passive")
        ok, cpu, wall, err = bp.run_child(cmd, env)
        r = {"ok": ok and mesh.exists(), "cpu": cpu, "wall": wall, "error": err or ("" if mesh.exists() else "no mesh.ply")}
        if r["ok"]:
            try:
                r.update(measure(src, mesh))
            except Exception as e:  # a mesh the measuring tools cannot read
                r["ok"], r["error"] = False, f"measure: {e}"
        if method == OURS:
            r["noise_sigma_rel"] = noise_figure(out_dir / "report.json")
        results[method] = r
        log(f"{work.name:28s} {method:22s} {'ok' if r['ok'] else 'FAILED ' + r['error']} "
            f"cpu {cpu:.2f} s wall {wall:.1f} s")
    return results


# ---------------------------------------------------------------- acceptance criteria

def is_level(sigma, *levels):
    return sigma is not None and any(math.isclose(sigma, x) for x in levels)


def ratio(r, ref, key):
    if not (r["ok"] and ref["ok"]) or r.get(key) is None or not ref.get(key):
        return None
    return r[key] / ref[key]


def crit_ratio(key, limit, word):
    def f(row):
        x = ratio(row["results"][OURS], row["results"][REF], key)
        if x is None:
            return None, "no ratio (a run failed)"
        return x <= limit, f"{word} {x:.2f}× Open3D's"
    return f


def crit_nc(row):
    r, ref = row["results"][OURS], row["results"][REF]
    if not (r["ok"] and ref["ok"]):
        return None, "a run failed"
    a, b = r["normal_consistency"], ref["normal_consistency"]
    return a >= b, f"{a:.4f} vs {b:.4f}"


def crit_genus(within):
    def f(row):
        truth = row["truth"]
        if not truth["watertight"]:
            return None, "source not watertight"
        g = row["results"][OURS].get("genus")
        if g is None:
            return False, "no genus (output not watertight)"
        return abs(g - truth["genus"]) <= within, f"genus {g}, truth {truth['genus']}"
    return f


def crit_one(watertight):
    def f(row):
        if watertight and not row["truth"]["watertight"]:
            return None, "source not watertight"
        r = row["results"][OURS]
        holds = r.get("components") == 1 and (r["watertight"] or not watertight)
        return holds, f"{r.get('components')} components, {'watertight' if r['watertight'] else 'not watertight'}"
    return f


def crit_watertight(row):
    if not row["truth"]["watertight"]:
        return None, "source not watertight"
    r = row["results"][OURS]
    return r["watertight"], f"{r['boundary_edges']} boundary edges"


def crit_selfint(row):
    n = row["results"][OURS].get("self_intersections")
    return n == 0, f"{n} self-intersecting faces"


def crit_euler(row):
    truth, r = row["truth"], row["results"][OURS]
    if not truth["watertight"]:
        return None, "source not closed"
    if r.get("euler") is None:
        return False, "empty mesh"
    return abs(r["euler"] - truth["euler"]) <= 4, f"χ {r['euler']}, truth {truth['euler']}"


def crit_noise(row):
    est = row["results"][OURS].get("noise_sigma_rel")
    added = row["sigma"] / 100
    if est is None:
        return False, "no noise figure in report.json"
    return 1 / 1.5 <= est / added <= 1.5, f"{100 * est:.3f}% for {row['sigma']:g}% ({est / added:.2f}×)"


# (inputs it applies to, criterion, check of one row -> (holds or None where it does not apply, detail))
CRITERIA = [
    ("σ 0.25% and 0.5%", lambda row: is_level(row["sigma"], 0.25, 0.5), [
        ("Chamfer ≤ 0.9× Open3D pipeline", crit_ratio("chamfer_rel", 0.9, "Chamfer")),
        ("normal consistency ≥ Open3D pipeline", crit_nc),
        ("genus of the source (watertight sources)", crit_genus(0)),
        ("one watertight component (watertight sources)", crit_one(True)),
        ("0 self-intersecting faces", crit_selfint),
        ("CPU ≤ 0.5× Open3D pipeline", crit_ratio("cpu", 0.5, "CPU")),
    ]),
    ("σ 1%", lambda row: is_level(row["sigma"], 1.0), [
        ("one component", crit_one(False)),
        ("genus within 1 of the source's (watertight sources)", crit_genus(1)),
        ("normal consistency ≥ Open3D pipeline", crit_nc),
    ]),
    ("σ 0", lambda row: is_level(row["sigma"], 0.0), [
        ("watertight (watertight sources)", crit_watertight),
        ("genus of the source (watertight sources)", crit_genus(0)),
    ]),
    ("scans", lambda row: row["set"] == "scans", [
        ("Chamfer ≤ 0.8× Open3D pipeline", crit_ratio("chamfer_rel", 0.8, "Chamfer")),
        ("normal consistency ≥ Open3D pipeline", crit_nc),
        ("Euler characteristic within 4 of the source's (closed sources)", crit_euler),
    ]),
    ("σ > 0", lambda row: row["sigma"] is not None and row["sigma"] > 0, [
        ("noise figure within a factor 1.5 of the σ added", crit_noise),
    ]),
]


def summary(rows):
    """One line per criterion: on how many inputs stablesurf default meets it, and where not."""
    out = []
    for group, applies, checks in CRITERIA:
        mine = [row for row in rows if applies(row)]
        if not mine:
            continue
        for label, check in checks:
            verdicts = [(row, *(check(row) if row["results"][OURS]["ok"] else (False, "failed: " + bp.short(row["results"][OURS]["error"]))))
                        for row in mine]
            counted = [(row, holds, why) for row, holds, why in verdicts if holds is not None]
            fails = [f"{row['label']}: {why}" for row, holds, why in counted if not holds]
            skipped = sorted({why for _, holds, why in verdicts if holds is None})
            if not counted:
                out.append(f"- {group}, {label}: not applicable ({'; '.join(skipped)}).")
                continue
            line = f"- {group}, {label}: {sum(h for _, h, _ in counted)}/{len(counted)}"
            if skipped:
                line += f" ({len(verdicts) - len(counted)} not applicable: {'; '.join(skipped)})"
            out.append(line + (f"; fails on {'; '.join(fails)}." if fails else "."))
    return out


# ---------------------------------------------------------------- report

def table(rows, scans):
    fmt = bp.fmt
    d = ["| input | method | Chamfer | Chamfer / Open3D | normal cons. | F-score | Hausdorff | comp. | watertight | genus | χ | self-int. | tri. | CPU s | CPU / Open3D | noise figure |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        ref = row["results"][REF]
        for method in METHODS:
            r = row["results"][method]
            if not r["ok"]:
                d.append(f"| {row['cell']} | {method} | failed | | | | | | | | | | | {r['cpu']:.2f} | | {bp.short(r['error'])} |")
                continue
            noise = ""
            if method == OURS:
                est = r.get("noise_sigma_rel")
                added = row["facts"]["rms_rel"] if scans else row["sigma"] / 100
                noise = "—" if est is None else f"{100 * est:.3f}%" + (f" ({est / added:.2f}×)" if added else "")
            ch, cpu = ratio(r, ref, "chamfer_rel"), ratio(r, ref, "cpu")
            d.append(
                f"| {row['cell']} | {method} | {fmt(r.get('chamfer_rel'), '.3e')} | {fmt(ch, '.2f')} | "
                f"{fmt(r.get('normal_consistency'), '.4f')} | {fmt(r.get('fscore'), '.3f')} | "
                f"{fmt(r.get('hausdorff_rel'), '.2e')} | {fmt(r.get('components'), 'd')} | "
                f"{'yes' if r['watertight'] else 'no'} | {fmt(r.get('genus'), 'd')} | {fmt(r.get('euler'), 'd')} | "
                f"{fmt(r.get('self_intersections'), 'd')} | {r['triangles']} | {r['cpu']:.2f} | {fmt(cpu, '.2f')} | {noise} |"
            )
    d.append("")
    return d


def command_line(a):
    cmd = ["tools/bench_noise"]
    if a.quick:
        cmd.append("--quick")
    if a.models:
        cmd += ["--models", a.models]
    if a.sigmas:
        cmd += ["--sigmas", a.sigmas]
    if a.no_scans:
        cmd.append("--no-scans")
    return " ".join(cmd)


def binary_version(path):
    try:
        return subprocess.run([path, "--version"], capture_output=True, text=True, timeout=30).stdout.strip() or "unknown version"
    except (OSError, subprocess.SubprocessError):
        return "unknown version"


def section(a, rows, sources, baseline, total):
    noise_rows = [row for row in rows if row["set"] == "noise"]
    scan_rows = [row for row in rows if row["set"] == "scans"]
    open_src = [f"{s.name} ({s.truth['boundary_edges']} boundary edges)" for s in sources.values() if not s.truth["watertight"]]
    d = ["## Noisy and partial points, scored against the clean mesh\n"]
    d.append(
        f"Generated by `{command_line(a)}` on {datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, "
        f"total {total:.0f} s wall; binary {shown_binary(a.bin)} ({binary_version(a.bin)}). Machine: {bp.machine()}. Libraries: "
        f"{bp.versions()}. Seeds: {SEED} (input samples, noise, scanner), {MEASURE_SEED} (samples of the scored meshes); "
        f"N = {N_SAMPLES:,} samples per mesh. Do not edit by hand: regenerate with "
        "`bash tools/bench_peers_install.sh && tools/bench_noise` (the full run: about 17 min on 2 cores).\n"
    )
    d.append(
        "**What it checks.** The acceptance criteria of the default `run` on noisy, unoriented points, with "
        "the clean source mesh as the truth: at σ 0.25% and 0.5% of the diagonal, Chamfer ≤ 0.9× the Open3D "
        "pipeline's, normal consistency ≥ its, the source's genus, one watertight component, 0 self-intersecting "
        "faces, CPU ≤ 0.5× its; at σ 1%, one component, genus within 1, normal consistency ≥ Open3D's; at σ 0, "
        "watertight with the source's genus; on simulated scans, Chamfer ≤ 0.8× the Open3D pipeline's, normal "
        "consistency ≥ its, Euler characteristic within 4 of the source's (closed sources); the noise figure of "
        "`report.json` within a factor 1.5 of the σ added. The summary at the end counts where each holds.\n"
    )
    d.append(
        f"**Inputs.** Noise levels: {N_POINTS:,} points drawn area-uniformly on each source mesh of ../shared/data, "
        "Gaussian noise of σ (per axis, % of the source's bounding-box diagonal) added, no normals; the same "
        "sample positions at every σ. Sources not watertight per pymeshlab (genus n/a): "
        f"{', '.join(open_src) if open_src else 'none'}. Simulated scans of CAD parts: `fandisk.obj` and "
        "*holed_block*, a 2 × 2 × 0.7 block with a cylindrical through-hole of radius 0.45 (genus 1, made by the "
        f"script), seen by a range scanner simulated with Open3D's RaycastingScene from {len(SCAN_VIEWS)} views of "
        f"the upper hemisphere (azimuth/elevation {', '.join(f'{az}°/{el}°' for az, el in SCAN_VIEWS)}; the "
        f"underside unseen), {SCAN_RES} × {SCAN_RES} rays per view, {SCAN_POINTS:,} of the hits drawn at random, "
        f"Gaussian noise along each ray scaled to a median distance to the surface of {100 * SCAN_MEDIAN:g}% of the "
        "diagonal; *seen* is the share of the source's area within 1% of the diagonal of a clean hit. The input "
        "cell gives the source's genus and Euler characteristic χ (pymeshlab, as loaded).\n"
    )
    d.append(
        "**Methods**, each a child process. *stablesurf default*: `stablesurf run INPUT -o DIR --no-cache -q "
        "--formats ply,json`. *Open3D pipeline* (the reference of the ratios): `estimate_normals(KDTreeSearchParamKNN(30))`, "
        "`orient_normals_consistent_tangent_plane(30)`, `create_from_point_cloud_poisson(depth=8)`, vertices "
        "below the 1% density quantile removed. *Poisson, true normals*: the same Poisson and trim given the exact "
        "normal of each point's triangle (an upper bound for Poisson). Open3D runs with `OMP_WAIT_POLICY=passive`; "
        f"its CPU includes Python start-up and `import open3d` ({baseline:.2f} s alone). Runs over "
        f"{bp.TIMEOUT} s are failures.\n"
    )
    d.append(
        f"**Measures**, against the clean source, distances over its diagonal, from {N_SAMPLES:,} area-uniform "
        "samples of each mesh and exact closest points on the other (Open3D RaycastingScene). *Chamfer*: (mean "
        "distance output samples → source + mean distance source samples → output) / 2. *normal cons.*: mean "
        "over both sample sets of |n · n′|, n the normal of the sample's triangle, n′ that of the closest "
        f"triangle on the other mesh. *F-score*: 2PR / (P + R) at τ = {100 * TAU:g}% of the diagonal, P the share "
        "of output samples within τ of the source, R the share of source samples within τ of the output. "
        "*Hausdorff*: the largest of those sample distances. *comp.*: pieces of faces joined through shared "
        "vertices; *watertight*, *genus* (watertight meshes only): pymeshlab's topological measures; *χ*: "
        "V − E + F; *self-int.*: faces MeshLab selects as self-intersecting; *CPU s*: user + sys of the child. "
        "*noise figure*: `report.json`'s `noise.sigma_per_diagonal` (— when absent) and its ratio to the σ added "
        "(scans: to the RMS distance of the noisy points to the surface).\n"
    )
    for sigma in sorted({row["sigma"] for row in noise_rows}):
        d.append(f"### σ = {sigma:g}% of the diagonal\n")
        d.extend(table([row for row in noise_rows if row["sigma"] == sigma], False))
    if scan_rows:
        d.append("### Simulated scans of CAD parts\n")
        d.extend(table(scan_rows, True))
    d.append("### Summary (stablesurf default)\n")
    d.extend(summary(rows) or ["No input ran."])
    d.append("")
    return "\n".join(d)


def shown_binary(path):
    """The binary as the document names it: its path in the repository, else only its name."""
    try:
        return f"`{Path(path).resolve().relative_to(ROOT)}`"
    except ValueError:
        return f"`{Path(path).name}` (given by --bin)"


def existing_section(path):
    """The section of PATH between the markers, with them, or "" (for tools/bench_peers)."""
    text = Path(path).read_text() if Path(path).exists() else ""
    i = text.find(BEGIN)
    j = text.find(END, i) if i >= 0 else -1
    return text[i:j + len(END)] + "\n" if j >= 0 else ""


def write_section(path, text):
    """Replaces the text between the markers (appends it at the end when they are absent)."""
    path = Path(path)
    old = path.read_text() if path.exists() else ""
    block = f"{BEGIN}\n{text}{END}"
    i = old.find(BEGIN)
    j = old.find(END, i) if i >= 0 else -1
    if j >= 0:
        new = old[:i] + block + old[j + len(END):]
    else:
        new = old + ("" if not old or old.endswith("\n\n") else "\n" if old.endswith("\n") else "\n\n") + block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(new)


# ---------------------------------------------------------------- main

def main():
    ap = argparse.ArgumentParser(description="stablesurf against Open3D on noisy points and simulated scans")
    ap.add_argument("--quick", action="store_true", help=f"{QUICK[0]} at σ {QUICK[1]}%% only, no scans; written under target/")
    ap.add_argument("--models", help="models of the noise levels, comma-separated (default all): " + ",".join(m for m, _ in MODELS))
    ap.add_argument("--sigmas", help="noise levels in %% of the diagonal, comma-separated (default 0,0.25,0.5,1)")
    ap.add_argument("--no-scans", action="store_true", help="skip the simulated scans")
    ap.add_argument("--bin", default=str(ROOT / "target/release/stablesurf"), help="the stablesurf binary")
    ap.add_argument("--out", help="Markdown file whose section is regenerated (default docs/benchmarks.md)")
    ap.add_argument("--work", help="output meshes (default target/bench-noise/work)")
    ap.add_argument("--peer", nargs=3, metavar=("WHICH", "IN", "OUT"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.peer:
        peer_main(*a.peer)
        return
    known = dict(MODELS)
    models = a.models.split(",") if a.models else [m for m, _ in MODELS]
    if a.quick:
        models = [QUICK[0]]
    unknown = [m for m in models if m not in known]
    if unknown:
        ap.error(f"unknown model(s) {', '.join(unknown)}; known: {', '.join(known)}")
    sigmas = [QUICK[1]] if a.quick else [float(s) for s in a.sigmas.split(",")] if a.sigmas else SIGMAS
    target = ROOT / "target" / ("bench-noise-quick" if a.quick else "bench-noise")
    out = Path(a.out) if a.out else target / "benchmarks.md" if a.quick else ROOT / "docs" / "benchmarks.md"
    work = Path(a.work) if a.work else target / "work"
    inputs = ROOT / "target" / "bench-noise" / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    log(f"seed {SEED} (inputs), {MEASURE_SEED} (measuring samples), N = {N_SAMPLES}; binary {a.bin}")
    _, baseline, _, _ = bp.run_child([sys.executable, "-c", "import open3d"], dict(os.environ, OMP_WAIT_POLICY="passive"))
    rows, sources = [], {}
    for name in models:
        src = sources[name] = Source(name, DATA / known[name])
        for sigma in sigmas:
            pts, nrm = noisy_input(src, sigma, inputs)
            label = f"{name} σ {sigma:g}%"
            results = run_methods(a, src, pts, nrm, work / f"{name}_sigma{sigma:g}")
            rows.append({"set": "noise", "model": name, "source": src.file, "sigma": sigma, "label": label,
                         "cell": f"{name} ({src.truth_text()})", "input": str(pts), "truth": src.truth, "facts": {}, "results": results})
    if not (a.quick or a.no_scans):
        for name in SCAN_SOURCES:
            path = DATA / known[name] if name in known else inputs / f"{name}.ply"
            if not path.exists():
                holed_block(path)
            src = Source(name, path)
            pts, nrm, facts = scan_input(src, inputs)
            log(f"scan of {name}: {facts['points']} points of {facts['hits']} hits, median distance "
                f"{100 * facts['median_rel']:.3f}% of the diagonal, {100 * facts['seen_share']:.1f}% of the area seen")
            cell = (f"{name} ({src.truth_text()}; scan: {facts['points']:,} points, {100 * facts['seen_share']:.0f}% "
                    f"seen, RMS distance {100 * facts['rms_rel']:.2f}%)")
            results = run_methods(a, src, pts, nrm, work / f"scan_{name}")
            rows.append({"set": "scans", "model": name, "source": src.file, "sigma": None, "label": f"scan of {name}",
                         "cell": cell, "input": str(pts), "truth": src.truth, "facts": facts, "results": results})
    total = time.perf_counter() - start
    write_section(out, section(a, rows, sources, baseline, total))
    results_json = target / "results.json"
    results_json.write_text(json.dumps({"command": command_line(a), "bin": a.bin, "seed": SEED, "measure_seed": MEASURE_SEED,
                                        "n_samples": N_SAMPLES, "total_wall_s": total, "open3d_import_cpu_s": baseline,
                                        "rows": rows}, indent=1))
    log(f"{total:.0f} s; {results_json}")
    print(out)


if __name__ == "__main__":
    main()
