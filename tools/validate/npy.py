"""Reads a stablesurf volume.npy with NumPy and checks it against its sidecar and a sphere.

Usage: python tools/validate/npy.py VOLUME.json [--sphere CX,CY,CZ,R --tolerance T]

VOLUME.json is the sidecar; the array is the file its "data" names, beside it. Checks: NumPy
loads it (np.load, format 1.0), float32 little-endian, C order, the sidecar's shape, finite
values; the sidecar's grid_to_world is the uniform scale voxel_size and the translation origin.
With --sphere: every value is within T of the analytic signed distance |p - c| - R at its voxel
centre p = origin + voxel_size * (i, j, k), and the sign is right wherever the analytic
distance is farther than T from zero.

Prints one JSON line with the figures and a "problems" list; exits 0 when there are no
problems, 1 otherwise.
"""

import argparse
import json
import os
import sys

import numpy as np


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("sidecar")
    parser.add_argument("--sphere")
    parser.add_argument("--tolerance", type=float, default=0.0)
    args = parser.parse_args()
    with open(args.sidecar) as f:
        side = json.load(f)
    path = os.path.join(os.path.dirname(os.path.abspath(args.sidecar)), side["data"])
    problems = []
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
    volume = np.load(path)
    report = {
        "file": path,
        "format_version": list(version),
        "dtype": volume.dtype.str,
        "shape": list(volume.shape),
        "c_order": bool(volume.flags["C_CONTIGUOUS"]),
    }
    if version != (1, 0):
        problems.append(f"format version {version}, expected (1, 0)")
    if volume.dtype.str != "<f4":
        problems.append(f"dtype {volume.dtype.str}, expected <f4")
    if list(volume.shape) != side["shape"]:
        problems.append(f"shape {volume.shape} differs from the sidecar's {side['shape']}")
    if not np.isfinite(volume).all():
        problems.append("values that are not finite")
    h = side["voxel_size"]
    o = np.array(side["origin"], dtype=np.float64)
    m = np.array(side["grid_to_world"], dtype=np.float64)
    want = np.diag([h, h, h, 1.0])
    want[:3, 3] = o
    if np.abs(m - want).max() > 1e-12 * max(1.0, np.abs(want).max()):
        problems.append("grid_to_world is not the voxel size and origin")
    report["min"] = float(volume.min())
    report["max"] = float(volume.max())
    if args.sphere:
        cx, cy, cz, r = (float(v) for v in args.sphere.split(","))
        i, j, k = np.meshgrid(*(np.arange(n) for n in volume.shape), indexing="ij")
        p = np.stack([i, j, k, np.ones_like(i)], axis=-1).astype(np.float64) @ m.T
        truth = np.sqrt((p[..., 0] - cx) ** 2 + (p[..., 1] - cy) ** 2 + (p[..., 2] - cz) ** 2) - r
        err = np.abs(volume.astype(np.float64) - truth)
        report["max_error"] = float(err.max())
        report["mean_error"] = float(err.mean())
        far = np.abs(truth) > args.tolerance
        wrong = int((np.sign(volume[far]) != np.sign(truth[far])).sum())
        report["sign_errors"] = wrong
        report["inside_voxels"] = int((volume < 0).sum())
        if err.max() > args.tolerance:
            problems.append(f"max error {err.max()} over the tolerance {args.tolerance}")
        if wrong:
            problems.append(f"{wrong} voxels with the wrong sign")
    report["problems"] = problems
    print(json.dumps(report))
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
