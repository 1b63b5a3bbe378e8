#!/usr/bin/env python3
"""Mean signed distance of meshes to an exact sphere or torus: at the vertices and over the area.

Usage: tools/validate/.venv/bin/python tools/mesh_bias.py SHAPE MESH.ply [MESH.ply ...]
[--samples N] [--seed S]

SHAPE is one of
  sphere:R            the sphere of radius R about the origin
  torus:R:r           the torus about the z axis, tube radius r about the circle of radius R
(the shapes of `bench_peers_inputs` are sphere:1 and torus:1:0.4). Needs numpy and open3d (to read
the mesh): `bash tools/bench_peers_install.sh` sets them up in tools/validate/.venv.

Prints, per mesh, as fractions of the diagonal of the shape's bounding box (positive: outside the
shape): the mean and rms of the exact signed distance at the vertices (how a check of the mesh
against the shape usually measures it), and its mean over the area, from N area-uniform samples
(default 400,000, seed 1). A mesh whose vertices lie on the surface has a mean near 0 at the
vertices and a negative one over the area where the surface curves (its flat facets lie inside).
"""

import argparse
import math
import sys

import numpy as np


def parse_shape(text):
    """(signed distance function, bounding-box diagonal) of a SHAPE argument."""
    name, *values = text.split(":")
    try:
        values = [float(v) for v in values]
    except ValueError:
        values = None
    if values and not all(math.isfinite(v) for v in values):
        values = None
    if name == "sphere" and values and len(values) == 1 and values[0] > 0:
        (radius,) = values
        return (lambda p: np.linalg.norm(p, axis=1) - radius), 2 * radius * np.sqrt(3)
    if name == "torus" and values and len(values) == 2 and 0 < values[1] < values[0]:
        big, small = values

        def distance(p):
            q = np.hypot(p[:, 0], p[:, 1]) - big
            return np.hypot(q, p[:, 2]) - small

        side = 2 * (big + small)
        return distance, np.sqrt(2 * side * side + 4 * small * small)
    raise ValueError(f"unknown shape {text!r}: give sphere:R or torus:R:r (R > r > 0)")


def area_samples(corners, n, seed):
    """n points uniform over the area of the triangles with `corners` (a, b, c), or None when
    they have no area."""
    a, b, c = corners
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not area.sum() > 0:
        return None
    rng = np.random.default_rng(seed)
    t = rng.choice(len(area), size=n, p=area / area.sum())
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    return (1 - r1) * a[t] + r1 * (1 - r2) * b[t] + r1 * r2 * c[t]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shape", help="sphere:R or torus:R:r")
    parser.add_argument("meshes", nargs="+", metavar="MESH.ply")
    parser.add_argument("--samples", type=int, default=400_000)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    try:
        distance, diagonal = parse_shape(args.shape)
    except ValueError as e:
        parser.error(str(e))
    if args.samples < 1:
        parser.error("--samples must be at least 1")
    import open3d as o3d

    for path in args.meshes:
        mesh = o3d.io.read_triangle_mesh(path)
        vertices = np.asarray(mesh.vertices, dtype=float)
        triangles = np.asarray(mesh.triangles, dtype=np.int64)
        if len(vertices) == 0 or len(triangles) == 0:
            print(f"error: {path}: no triangle mesh read (give a PLY, OBJ or STL mesh)", file=sys.stderr)
            sys.exit(1)
        corners = tuple(vertices[triangles[:, k]] for k in range(3))
        samples = area_samples(corners, args.samples, args.seed)
        if samples is None:
            print(f"error: {path}: the mesh has no area (every triangle is degenerate)", file=sys.stderr)
            sys.exit(1)
        at_vertices = distance(vertices) / diagonal
        over_area = distance(samples) / diagonal
        print(
            f"{path}: {len(vertices)} vertices; vertices mean {at_vertices.mean():+.2e} "
            f"rms {np.sqrt(np.mean(at_vertices**2)):.2e}; area mean {over_area.mean():+.2e}"
        )


if __name__ == "__main__":
    main()
