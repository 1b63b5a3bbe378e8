"""E57 files written by pye57 (libE57Format), read by stablesurf.

Usage: e57.py STABLESURF_BINARY WORK_DIR

Writes a sphere (radius 1.5, centre (10, -4, 2)) seen by four scanners around it as one E57
file with four scans: each scan holds the points facing its sensor (those it sees best) in the
scanner's own frame, with the scanner's pose (a rotation quaternion and a
translation) that puts them in the common frame, and no normals. Runs `stablesurf info --json`
and `stablesurf run` on it and checks that

- the point count is the sum of the scans' and the bounding box is the one of the points moved
  by their poses (1e-9 relative), which only holds if each pose is applied as E57 defines it;
- the mesh is one watertight piece on the sphere (every vertex within 2% of the radius), which
  needs every normal turned towards its own scan's sensor (outwards).

Prints one JSON line and exits non-zero on the first failure.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pye57
from plyfile import PlyData

CENTER = np.array([10.0, -4.0, 2.0])
RADIUS = 1.5
N_POINTS = 6000


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def sphere() -> np.ndarray:
    i = np.arange(N_POINTS)
    z = 1.0 - (2.0 * i + 1.0) / N_POINTS
    r = np.sqrt(1.0 - z * z)
    a = i * np.pi * (3.0 - np.sqrt(5.0))
    return CENTER + RADIUS * np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)


def write(path: Path) -> np.ndarray:
    """Writes the four scans; returns the points in the common frame as a reader must find them."""
    points = sphere()
    # Four sensors 20 units from the centre in tetrahedral directions, so that every point
    # faces one of them; each point is in the scan of the sensor it faces most, as a
    # registration would keep it.
    directions = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) / np.sqrt(3.0)
    sensors = [CENTER + 20.0 * d for d in directions]
    poses = [
        np.array([0.9, 0.1, -0.3, 0.2]),
        np.array([0.5, -0.5, 0.5, 0.5]),
        np.array([0.0, 1.0, 0.0, 0.0]),
        np.array([0.7, 0.0, 0.7, 0.1]),
    ]
    normals = (points - CENTER) / RADIUS

    def facing(sensor: np.ndarray) -> np.ndarray:
        to_sensor = sensor - points
        to_sensor /= np.linalg.norm(to_sensor, axis=1, keepdims=True)
        return np.einsum("ij,ij->i", normals, to_sensor)

    faces = np.stack([facing(sensor) for sensor in sensors])
    best = faces.argmax(axis=0)
    assert faces.max(axis=0).min() > 0.1, "every point faces a sensor"
    e57 = pye57.E57(str(path), mode="w")
    world = []
    for k, (sensor, q) in enumerate(zip(sensors, poses)):
        q = q / np.linalg.norm(q)
        seen = points[best == k]
        rotation = quaternion_matrix(q)
        # Scanner frame: world = R · local + t, with t the sensor's position.
        # pye57 stores unscaled coordinates as float32: the reader must find those values.
        local = ((seen - sensor) @ rotation).astype(np.float32).astype(np.float64)
        e57.write_scan_raw(
            {
                "cartesianX": local[:, 0].copy(),
                "cartesianY": local[:, 1].copy(),
                "cartesianZ": local[:, 2].copy(),
            },
            name=f"scan {k}",
            rotation=q,
            translation=sensor,
        )
        world.append(local @ rotation.T + sensor)
    e57.close()
    return np.concatenate(world)


def main() -> int:
    binary, work = sys.argv[1], Path(sys.argv[2])
    path = work / "four_scans.e57"
    expected = write(path)
    info = json.loads(
        subprocess.run(
            [binary, "info", "--json", str(path)], check=True, capture_output=True, text=True
        ).stdout
    )
    assert info["format"] == "e57", info
    assert info["points"] == len(expected), (info["points"], len(expected))
    assert len(info["scans"]) == 4, info["scans"]
    for got, want in zip(
        info["bbox_min"] + info["bbox_max"], list(expected.min(0)) + list(expected.max(0))
    ):
        assert abs(got - want) <= 1e-9 * max(1.0, abs(want)), (got, want, info)
    out = work / "four_scans.out"
    subprocess.run(
        [binary, "-q", "run", str(path), "-o", str(out), "--no-cache", "--formats", "ply,json"],
        check=True,
        capture_output=True,
        text=True,
    )
    report = json.loads((out / "report.json").read_text())
    vertex = PlyData.read(str(out / "mesh.ply"))["vertex"]
    mesh = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
    off_sphere = float(np.abs(np.linalg.norm(mesh - CENTER, axis=1) - RADIUS).max())
    assert off_sphere <= 0.02 * RADIUS, off_sphere
    assert report["mesh"]["watertight"] and report["mesh"]["components"] == 1, report["mesh"]
    print(
        json.dumps(
            {
                "file": path.name,
                "format": info["format"],
                "points": info["points"],
                "scans": len(info["scans"]),
                "mesh_vertices": len(mesh),
                "mesh_max_off_sphere": off_sphere,
                "watertight": report["mesh"]["watertight"],
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
