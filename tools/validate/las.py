"""LAS and LAZ files written by laspy (LAZ through its lazrs backend), read by stablesurf.

Usage: las.py STABLESURF_BINARY WORK_DIR

Writes a sphere of 3000 points with colours and intensities, far from the origin (UTM-like
offsets, a 1 mm scale), as LAS 1.2 point format 3 and as LAZ; runs `stablesurf info --json`
and `stablesurf run` on each and checks that the point count and the bounding box are the ones
laspy wrote (exact to the scale), that colour and intensity are kept, and that the mesh lies on
the sphere, to 1% of its radius: at these coordinates mesh.ply holds double vertices (float32
would round them to 0.25 m).
Prints one JSON line per file and exits non-zero on the first failure.
"""

import json
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
from plyfile import PlyData

N_POINTS = 3000
CENTER = np.array([500_123.25, 4_000_456.5, 101.75])
RADIUS = 10.0
SCALE = 0.001


def sphere_points() -> np.ndarray:
    i = np.arange(N_POINTS)
    z = 1.0 - (2.0 * i + 1.0) / N_POINTS
    r = np.sqrt(1.0 - z * z)
    a = i * np.pi * (3.0 - np.sqrt(5.0))
    return CENTER + RADIUS * np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def write(path: Path) -> laspy.LasData:
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([SCALE] * 3)
    header.offsets = np.array([500_000.0, 4_000_000.0, 0.0])
    las = laspy.LasData(header)
    p = sphere_points()
    las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
    las.intensity = (np.arange(N_POINTS) % 4096).astype(np.uint16)
    las.red = (np.arange(N_POINTS) * 21 % 65536).astype(np.uint16)
    las.green = np.full(N_POINTS, 32768, dtype=np.uint16)
    las.blue = np.full(N_POINTS, 65535, dtype=np.uint16)
    if path.suffix == ".laz":
        las.write(str(path), laz_backend=laspy.LazBackend.Lazrs)
    else:
        las.write(str(path))
    # What a reader must find: the stored integers times the scale plus the offset.
    return laspy.read(str(path), laz_backend=laspy.LazBackend.Lazrs)


def check(binary: str, path: Path, out_dir: Path) -> dict:
    stored = write(path)
    expected_min = [float(stored.x.min()), float(stored.y.min()), float(stored.z.min())]
    expected_max = [float(stored.x.max()), float(stored.y.max()), float(stored.z.max())]
    info = json.loads(
        subprocess.run(
            [binary, "info", "--json", str(path)], check=True, capture_output=True, text=True
        ).stdout
    )
    fmt = path.suffix[1:]
    assert info["format"] == fmt, info
    assert info["points"] == N_POINTS, info
    assert info["has_colours"] and info["has_intensity"], info
    for got, want in zip(info["bbox_min"] + info["bbox_max"], expected_min + expected_max):
        assert abs(got - want) <= 1e-9 * abs(want), (got, want, info)
    subprocess.run(
        [binary, "-q", "run", str(path), "-o", str(out_dir), "--no-cache", "--formats", "ply,json"],
        check=True,
        capture_output=True,
        text=True,
    )
    report = json.loads((out_dir / "report.json").read_text())
    imported = report["stages"][0]["figures"]
    assert imported["points"] == N_POINTS, imported
    vertex = PlyData.read(str(out_dir / "mesh.ply"))["vertex"]
    assert vertex["x"].dtype == np.float64, vertex["x"].dtype
    mesh = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    assert len(mesh) > 0
    off_sphere = np.abs(np.linalg.norm(mesh - CENTER, axis=1) - RADIUS).max()
    assert off_sphere < 0.01 * RADIUS, off_sphere
    return {
        "file": path.name,
        "format": info["format"],
        "points": info["points"],
        "bbox_min": info["bbox_min"],
        "bbox_max": info["bbox_max"],
        "mesh_vertices": len(mesh),
        "mesh_max_off_sphere": float(off_sphere),
        "watertight": report["mesh"]["watertight"],
    }


def main() -> int:
    binary, work = sys.argv[1], Path(sys.argv[2])
    for name in ("sphere.las", "sphere.laz"):
        result = check(binary, work / name, work / (name + ".out"))
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
