"""Tests of the Python package against the command line and against analytic shapes.

Run with `python/.venv/bin/python -m pytest tests/python` after `bash tools/python_install.sh`.
The command line is run through `cargo run --release` (a no-op build when target/release is
fresh). Every file is written inside pytest's temporary folders; runs use --no-cache.
"""

import json
import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

import stablesurf

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
BUNNY = DATA / "bunny_zipper.ply"


def cli(*args):
    """Runs the stablesurf binary (release build) with `args`; fails the test on an error."""
    cmd = ["cargo", "run", "--release", "--quiet", "--bin", "stablesurf", "--", *map(str, args)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, f"{' '.join(cmd)} failed:\n{done.stderr}"
    return done


def fibonacci_sphere(n, radius):
    """`n` points spread evenly on a sphere of `radius` about the origin, and their unit normals."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / n)
    azimuth = math.pi * (1.0 + math.sqrt(5.0)) * i
    normals = np.column_stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)]
    )
    return radius * normals, normals


def test_bunny_mesh_is_the_cli_mesh_byte_for_byte(tmp_path):
    if not BUNNY.exists():
        if os.environ.get("CI"):
            pytest.fail(f"{BUNNY} is missing (CI is set, so the real-data test may not skip)")
        pytest.skip(f"{BUNNY} is absent")
    cli("run", BUNNY, "-o", tmp_path / "out", "--no-cache", "-q", "--formats", "ply")
    ply = PlyData.read(str(tmp_path / "out" / "mesh.ply"))
    vertex = ply["vertex"]
    ply_vertices = np.column_stack([vertex["x"], vertex["y"], vertex["z"]])
    ply_normals = np.column_stack([vertex["nx"], vertex["ny"], vertex["nz"]])
    ply_faces = np.vstack(ply["face"]["vertex_indices"])

    scan = stablesurf.read_points(BUNNY)
    assert len(scan) == 35947 and scan.faces.shape == (69451, 3)
    result = stablesurf.reconstruct(scan)

    # The PLY stores float32 positions and normals and int32 indices: the same conversion of
    # the package's arrays gives the same bytes.
    assert ply_vertices.dtype == np.float32 and ply_faces.dtype == np.int32
    assert result.vertices.shape == ply_vertices.shape
    assert result.vertices.astype(np.float32).tobytes() == ply_vertices.tobytes()
    assert result.normals.astype(np.float32).tobytes() == ply_normals.tobytes()
    assert result.faces.shape == ply_faces.shape
    assert result.faces.astype(np.int32).tobytes() == ply_faces.tobytes()
    # The report's figures are the CLI's (the bunny's README row: watertight, no crossing).
    assert result.watertight and result.manifold and result.self_intersections == 0
    assert result.report["mesh"]["vertices"] == len(ply_vertices)
    assert 0 < result.accuracy["mean_relative"] < 2e-3


def test_sphere_with_analytic_normals_lies_on_the_sphere():
    radius = 2.0
    points, normals = fibonacci_sphere(4000, radius)
    result = stablesurf.reconstruct(points, normals)
    distance = np.linalg.norm(result.vertices, axis=1)
    # Every vertex within 0.2% of the radius (the detail blend of 4,000 exact samples).
    assert np.max(np.abs(distance - radius)) < 2e-3 * radius
    assert result.watertight and result.manifold and result.self_intersections == 0
    # Unit normals pointing outwards, along the radius.
    unit = result.vertices / distance[:, None]
    assert np.min(np.sum(unit * result.normals, axis=1)) > 0.99
    assert result.faces.dtype == np.uint32 and result.faces.max() < len(result.vertices)
    # The thread count does not change the mesh.
    one = stablesurf.reconstruct(points, normals, threads=1)
    assert one.vertices.tobytes() == result.vertices.tobytes()
    assert one.faces.tobytes() == result.faces.tobytes()


def test_depth_given_is_kept_in_detail_mode():
    points, normals = fibonacci_sphere(3000, 1.0)

    def meshing_depth(result):
        (stage,) = [s for s in result.report["stages"] if s["stage"] == "polygonize"]
        return stage["figures"]["depth"]

    # Detail mode takes its depth from the points' spacing (here 6) unless one is given, as
    # `run --depth` does.
    assert meshing_depth(stablesurf.reconstruct(points, normals)) == 6
    assert meshing_depth(stablesurf.reconstruct(points, normals, depth=5)) == 5


def test_noisy_points_are_measured_and_smoothed_unless_smooth_is_zero():
    # 12,000 points of the unit sphere without normals, moved by Gaussian noise of 0.02 per
    # coordinate (about 0.6 of their spacing).
    points, _ = fibonacci_sphere(12000, 1.0)
    noisy = points + np.random.default_rng(5).normal(0.0, 0.02, points.shape)
    smoothed = stablesurf.reconstruct(noisy)
    exact = stablesurf.reconstruct(noisy, smooth=0)
    noise = smoothed.report["noise"]
    # The figure within 20% of the noise added, and averaged by default only.
    assert 0.8 < noise["sigma"] / 0.02 < 1.2
    assert noise["smoothed_per_diagonal"] > 0 and exact.report["noise"]["smoothed_per_diagonal"] == 0

    def mean_error(result):
        return np.mean(np.abs(np.linalg.norm(result.vertices, axis=1) - 1.0))

    assert mean_error(smoothed) < 0.5 * mean_error(exact)
    assert smoothed.watertight and smoothed.self_intersections == 0
    with pytest.raises(ValueError, match="smooth"):
        stablesurf.reconstruct(noisy, smooth=11)


def test_global_mode_gives_the_polynomial_and_its_mesh():
    points, normals = fibonacci_sphere(3000, 1.5)
    result = stablesurf.reconstruct(points, normals, mode="global", degree=4, depth=5)
    assert result.polynomial is not None and result.polynomial.degree == 4
    # The mesh's vertices are on the zero set: |f| small against f's range on the data's scale.
    values = result.polynomial.evaluate(result.vertices)
    assert np.max(np.abs(values)) < 1e-6
    assert np.max(np.abs(np.linalg.norm(result.vertices, axis=1) - 1.5)) < 1e-3 * 1.5


def test_bad_input_shape_is_a_value_error():
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\).*got shape \(5, 2\)"):
        stablesurf.reconstruct(np.zeros((5, 2)))
    points, normals = fibonacci_sphere(100, 1.0)
    with pytest.raises(ValueError, match=r"3 normals for 100 points"):
        stablesurf.reconstruct(points, normals[:3])
    with pytest.raises(ValueError, match=r"non-finite coordinate"):
        bad = points.copy()
        bad[7, 1] = np.nan
        stablesurf.fit(bad)
    with pytest.raises(ValueError, match=r"depth takes a whole number from 1 to 12, got 13"):
        stablesurf.reconstruct(points, normals, depth=13)
    with pytest.raises(ValueError, match=r"mode takes"):
        stablesurf.reconstruct(points, normals, mode="fast")
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'colour'"):
        stablesurf.reconstruct(points, normals, colour=1)
    # The library's own message: an odd degree cannot be bounded.
    with pytest.raises(ValueError, match=r"odd"):
        stablesurf.fit(points, normals, degree=3)
    with pytest.raises(OSError, match=r"cannot read"):
        stablesurf.read_points(ROOT / "no-such-scan.ply")


def test_fit_equals_the_cli_model_json(tmp_path):
    # An ellipsoid with its normals, as an XYZ file both sides read.
    points, normals = fibonacci_sphere(2000, 1.0)
    points = points * np.array([1.0, 0.7, 0.5]) + np.array([0.3, -0.2, 0.1])
    scaled = normals / np.array([1.0, 0.7, 0.5])
    normals = scaled / np.linalg.norm(scaled, axis=1)[:, None]
    xyz = tmp_path / "ellipsoid.xyz"
    np.savetxt(xyz, np.hstack([points, normals]), fmt="%.17g")
    cli("fit", xyz, "-o", tmp_path / "model.json", "--degree", "6", "-q")
    model = json.loads((tmp_path / "model.json").read_text())

    scan = stablesurf.read_points(xyz)
    assert np.array_equal(scan.points, np.loadtxt(xyz)[:, :3])
    poly = stablesurf.fit(scan, degree=6)
    assert poly.degree == model["degree"] == 6
    assert poly.coefficients.tolist() == model["coefficients"]
    assert poly.center.tolist() == model["normalization"]["center"]
    assert poly.scale == model["normalization"]["scale"]
    assert json.loads(poly.to_json())["coefficients"] == model["coefficients"]
    # The same arrays give the same fit as the file.
    again = stablesurf.fit(scan.points, scan.normals, degree=6)
    assert again.coefficients.tobytes() == poly.coefficients.tobytes()
    # f < 0 inside, f > 0 outside, f ≈ 0 on the data (relative to f's size one step out).
    centre = np.array([[0.3, -0.2, 0.1]])
    assert poly.evaluate(centre)[0] < 0 < poly.evaluate(centre + [[3.0, 0.0, 0.0]])[0]
    on = np.abs(poly.evaluate(points))
    off = np.abs(poly.evaluate(points + 0.05 * normals))
    assert np.median(on) < 0.1 * np.median(off)
