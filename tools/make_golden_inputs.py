#!/usr/bin/env python3
"""Writes the synthetic golden inputs (deterministic: no randomness, fixed formatting).

sphere-d2/input.xyz: 500 points on a sphere of radius 2 centred at (1, 2, 3), exact normals.
torus-d4/input.xyz: 2000 points on a torus (R = 1, r = 0.4) scaled by 2.5 and moved by (1, -2, 0.5),
with exact normals (the shape of ../shared/cases/torus-d6).
"""
import math
import os

here = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "golden")


def write(path, rows, comment):
    with open(path, "w") as f:
        f.write(f"# {comment}\n")
        for r in rows:
            f.write(" ".join(f"{v:.9f}" for v in r) + "\n")


def sphere(n):
    g = math.pi * (3.0 - math.sqrt(5.0))
    for i in range(n):
        z = 1.0 - 2.0 * (i + 0.5) / n
        r = math.sqrt(1.0 - z * z)
        t = g * i
        nx, ny, nz = r * math.cos(t), r * math.sin(t), z
        yield (1 + 2 * nx, 2 + 2 * ny, 3 + 2 * nz, nx, ny, nz)


def torus(nu, nv, big=1.0, small=0.4, scale=2.5, shift=(1.0, -2.0, 0.5)):
    for i in range(nu):
        u = 2 * math.pi * (i + 0.5) / nu
        for j in range(nv):
            v = 2 * math.pi * (j + 0.37 * (i % 3)) / nv
            nx, ny, nz = math.cos(u) * math.cos(v), math.sin(u) * math.cos(v), math.sin(v)
            x = (big + small * math.cos(v)) * math.cos(u)
            y = (big + small * math.cos(v)) * math.sin(u)
            z = small * math.sin(v)
            yield (scale * x + shift[0], scale * y + shift[1], scale * z + shift[2], nx, ny, nz)


write(os.path.join(here, "sphere-d2", "input.xyz"), sphere(500), "sphere, radius 2, centre (1, 2, 3)")
write(os.path.join(here, "torus-d4", "input.xyz"), torus(50, 40), "torus R=1 r=0.4, scaled 2.5, moved (1,-2,0.5)")
