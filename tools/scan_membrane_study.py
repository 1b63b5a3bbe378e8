#!/usr/bin/env python3
"""Where the Chamfer of the simulated scans of tools/bench_noise comes from, and what closing the
scan's open rim with a membrane would do to it (the figures are in docs/defaults.md,
"Partial scans of closed parts: a membrane over the open rim").

Run in tools/validate/.venv (install: bash tools/bench_peers_install.sh):

    tools/validate/.venv/bin/python tools/scan_membrane_study.py --bin target/release/stablesurf

For each simulated scan of bench_noise (the same inputs, written under target/bench-noise/inputs
when missing), it runs `BIN run INPUT --no-cache -q --formats ply,json` with the trim on (the
default) and off, derives the variants below from the trimmed mesh in Python, and scores each
against the clean source as bench_noise does (bench_noise.measure), with the Chamfer's source ->
output half split by where the source sample lies: *seen* when a scan point lies within 2% of
the diagonal of it, *unseen* otherwise (the underside the scanner never looked at).

Variants (experiments, not what `run` does):
  - fill: every boundary loop at least --fill-perimeter of the diagonal long is closed by a fan
    from its centroid, split 1 -> 4 four times, and its inner vertices moved to the membrane the
    loop spans (uniform Laplace, the loop fixed: the operator of src/trim/fair.rs). The fill's
    triangles are not checked against the mesh: its self-intersections are counted, not avoided.
  - flat fill (holed block only, an oracle): the fill's inner vertices put on the source's true
    bottom plane, to separate the membrane's height from its shape.
  - peel: kept triangles on the boundary whose vertices have fewer scan points within 2% of the
    diagonal than 30% of the median count over the mesh's vertices are removed, repeatedly (the rim
    drawn back from where the trim's noise allowance leaves it to where the points thin out).
  - peel + fill: both, the fill of loops at least --fill-perimeter long.

Then the one-view share of the default meshes of the scans and of single raw range views
(--views): the largest share of the mesh's area whose normal n has n . v > 0 (and > 0.2) over
4,000 directions v spread evenly on the sphere (a Fibonacci lattice). A single view sees only
surface that faces it, so the share is near 1 there; a ring of views sees walls all around.
"""

import argparse
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_noise as bn  # noqa: E402

SEEN_SHARE = 0.02  # a source sample with a scan point within this share of the diagonal is seen
PEEL_RADIUS = 0.02  # share of the diagonal: the ball in which the peel counts scan points
PEEL_SHARE = 0.3  # a rim vertex with fewer points than this share of the median count is peeled
FILL_LEVELS = 4  # 1 -> 4 splits of the fan


def boundary_loops(t):
    """The boundary loops of triangles t, each a list of vertex indices in the mesh's direction."""
    edges = set()
    for tri in t:
        for k in range(3):
            edges.add((int(tri[k]), int(tri[(k + 1) % 3])))
    nxt = {a: b for (a, b) in edges if (b, a) not in edges}
    seen, loops = set(), []
    for start in sorted(nxt):
        if start in seen:
            continue
        lp, x = [start], nxt[start]
        seen.add(start)
        while x != start and x in nxt and x not in seen:
            lp.append(x)
            seen.add(x)
            x = nxt[x]
        loops.append(lp)
    return loops


def fill(v, t, min_perimeter, flat_z=None):
    """(vertices, triangles) with the loops at least min_perimeter long closed (see the docstring)."""
    import numpy as np
    import scipy.sparse as sparse
    import scipy.sparse.linalg as sparse_linalg

    verts, added = list(v), []
    for lp in boundary_loops(t):
        p = v[lp]
        if np.linalg.norm(np.roll(p, -1, 0) - p, axis=1).sum() < min_perimeter:
            continue
        centre = len(verts)
        verts.append(p.mean(0))
        tris = [[lp[(i + 1) % len(lp)], lp[i], centre] for i in range(len(lp))]
        for _ in range(FILL_LEVELS):
            mid = {}

            def midpoint(a, b):
                key = (min(a, b), max(a, b))
                if key not in mid:
                    mid[key] = len(verts)
                    verts.append((np.asarray(verts[a]) + np.asarray(verts[b])) / 2)
                return mid[key]

            split = []
            for a, b, c in tris:
                ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
                split += [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
            tris = split
        added += tris
    verts = np.array(verts)
    if not added:
        return verts, t
    added = np.array(added, dtype=np.int64)
    # The membrane: the fill's vertices off its own boundary (the loop and the midpoints on it) at
    # the mean of their neighbours.
    free = np.zeros(len(verts), bool)
    free[len(v):] = True
    count = defaultdict(int)
    for tri in added:
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            count[(min(a, b), max(a, b))] += 1
    for (a, b), n in count.items():
        if n == 1:
            free[a] = free[b] = False
    index = -np.ones(len(verts), int)
    moving = np.where(free)[0]
    index[moving] = np.arange(len(moving))
    rows, cols, vals = [], [], []
    rhs = np.zeros((len(moving), 3))
    for tri in added:
        for k in range(3):
            a, b = tri[k], tri[(k + 1) % 3]
            for x, y in ((a, b), (b, a)):
                if free[x]:
                    rows.append(index[x])
                    cols.append(index[x])
                    vals.append(1.0)
                    if free[y]:
                        rows.append(index[x])
                        cols.append(index[y])
                        vals.append(-1.0)
                    else:
                        rhs[index[x]] += verts[y]
    solve = sparse_linalg.factorized(sparse.csc_matrix((vals, (rows, cols)), shape=(len(moving),) * 2))
    for a in range(3):
        verts[moving, a] = solve(rhs[:, a])
    if flat_z is not None:
        verts[moving, 2] = flat_z
    return verts, np.vstack([t, added])


def peel(v, t, points, diag):
    """The triangles t without the thinly supported rim (see the docstring)."""
    import numpy as np
    from scipy.spatial import cKDTree

    count = np.array([len(x) for x in cKDTree(points).query_ball_point(v, PEEL_RADIUS * diag)])
    thin = count < PEEL_SHARE * np.median(count)
    keep = np.ones(len(t), bool)
    while True:
        edges = defaultdict(int)
        for tri in t[keep]:
            for k in range(3):
                a, b = tri[k], tri[(k + 1) % 3]
                edges[(min(a, b), max(a, b))] += 1
        rim = np.zeros(len(v), bool)
        for (a, b), n in edges.items():
            if n == 1:
                rim[a] = rim[b] = True
        drop = keep & (rim & thin)[t].any(axis=1)
        if not drop.any():
            return t[keep]
        keep &= ~drop


def write_mesh(path, v, t):
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    o3d.io.write_triangle_mesh(str(path), mesh)


def score(src, path, seen):
    """bench_noise's scores of the mesh at path, with the source -> output half split."""
    import numpy as np

    r = bn.measure(src, path)
    _, v, t = bn.read_mesh(path)
    v = v - src.center
    d_src, _ = bn.closest(bn.scene_of(v, t), bn.face_normals(v, t), src.samples, src.sample_normals)
    n = len(d_src)
    r["src_seen"] = d_src[seen].sum() / n / src.diag
    r["src_unseen"] = d_src[~seen].sum() / n / src.diag
    r["out_src"] = 2 * r["chamfer_rel"] - (r["src_seen"] + r["src_unseen"])
    r["unseen_mean"] = float(d_src[~seen].mean()) / src.diag
    return r


def one_view_share(path, threshold):
    """The largest share of the mesh's area whose normal n has n . v > threshold, over the
    directions v of a 4,000-point Fibonacci lattice on the sphere."""
    import numpy as np

    _, v, t = bn.read_mesh(path)
    k = np.arange(4000) + 0.5
    polar, azimuth = np.arccos(1 - 2 * k / 4000), 2 * np.pi * k / ((1 + 5 ** 0.5) / 2)
    dirs = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], 1)
    c = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    area = np.linalg.norm(c, axis=1)
    n = c / np.maximum(area, 1e-300)[:, None]
    return float((area[:, None] * ((n @ dirs.T) > threshold)).sum(0).max() / area.sum())


def main():
    import numpy as np
    import open3d as o3d
    from scipy.spatial import cKDTree

    ap = argparse.ArgumentParser(description="the simulated scans' Chamfer, split, with and without a membrane")
    ap.add_argument("--bin", required=True, help="the stablesurf binary")
    ap.add_argument("--work", default=str(bn.ROOT / "target" / "scan-membrane"), help="output folder")
    ap.add_argument("--fill-perimeter", type=float, default=2.0,
                    help="loops at least this share of the diagonal long are filled (default 2: each"
                         " scan's largest loop only, 2.8 and 3.3 of the diagonal; the next are under 1.9)")
    ap.add_argument("--views", nargs="*", default=[str(bn.DATA / "bun000.ply"), str(bn.DATA / "bunny-scans" / "bun090.ply"),
                                                   str(bn.DATA / "bunny-scans" / "top2.ply")],
                    help="single raw range views whose one-view share is given too")
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    inputs = bn.ROOT / "target" / "bench-noise" / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    print("| scan | variant | Chamfer | output → source | source → output, seen | source → output, unseen "
          "(mean distance of an unseen sample) | boundary edges | χ | self-int. |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in bn.SCAN_SOURCES:
        known = dict(bn.MODELS)
        path = bn.DATA / known[name] if name in known else inputs / f"{name}.ply"
        if not path.exists():
            bn.holed_block(path)
        src = bn.Source(name, path)
        pts, _, _ = bn.scan_input(src, inputs)
        points = np.asarray(o3d.io.read_point_cloud(str(pts)).points)
        near, _ = cKDTree(points - src.center).query(src.samples)
        seen = near <= SEEN_SHARE * src.diag
        meshes = {}
        for trim in ("auto", "off"):
            out = work / f"{name}_trim_{trim}"
            subprocess.run([a.bin, "run", str(pts), "-o", str(out), "--no-cache", "-q", "--formats", "ply,json",
                            "--trim", trim], check=True)
            meshes[f"default (trim {trim})"] = out / "mesh.ply"
        _, v, t = bn.read_mesh(meshes["default (trim auto)"])
        # The diagonal of the scan points, as the trim's shares are.
        diag = float(np.linalg.norm(points.max(0) - points.min(0)))
        variants = {"fill": fill(v, t, a.fill_perimeter * diag)}
        if name == "holed_block":
            variants["flat fill (oracle: the true bottom plane)"] = fill(
                v, t, a.fill_perimeter * diag, flat_z=float(src.v[:, 2].min()))
        peeled = peel(v, t, points, diag)
        variants["peel"] = (v, peeled)
        variants["peel + fill"] = fill(v, peeled, a.fill_perimeter * diag)
        for label, (vv, tt) in variants.items():
            out = work / f"{name}_{label.split(' (')[0].replace(' + ', '_').replace(' ', '_')}.ply"
            write_mesh(out, vv, tt)
            meshes[label] = out
        for label, mesh in meshes.items():
            r = score(src, mesh, seen)
            print(f"| {name} | {label} | {r['chamfer_rel']:.3e} | {r['out_src']:.3e} | {r['src_seen']:.3e} | "
                  f"{r['src_unseen']:.3e} ({r['unseen_mean']:.2e}) | {r['boundary_edges']} | {r['euler']} | "
                  f"{r['self_intersections']} |", flush=True)
        nz, z = src.sample_normals[~seen, 2], src.samples[:, 2]
        height = (src.samples[~seen, 2] - z.min()) / np.ptp(z)
        print(f"| {name} | seen share of the source's samples: {seen.mean():.3f}; of the unseen ones, facing down "
              f"(n_z < -0.9) {(nz < -0.9).mean():.2f}, on side walls (|n_z| < 0.3) {(abs(nz) < 0.3).mean():.2f}, "
              f"median height {np.median(height):.2f} of the part's | | | | | | | |")

    print()
    print("| mesh | one-view share, n . v > 0 | n . v > 0.2 |")
    print("|---|---|---|")
    shared = [(f"scan of {name}", work / f"{name}_trim_auto" / "mesh.ply") for name in bn.SCAN_SOURCES]
    for view in a.views:
        out = work / f"view_{Path(view).stem}"
        subprocess.run([a.bin, "run", view, "-o", str(out), "--no-cache", "-q", "--formats", "ply,json"], check=True)
        shared.append((f"single view {Path(view).name}", out / "mesh.ply"))
    for label, mesh in shared:
        print(f"| {label} | {one_view_share(mesh, 0.0):.3f} | {one_view_share(mesh, 0.2):.3f} |", flush=True)


if __name__ == "__main__":
    main()
