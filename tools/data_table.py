#!/usr/bin/env python3
"""Runs `stablesurf run` on every scan of ../shared/data and prints a Markdown table from the
reports: file, points, normals source, degree, κ, bounded, components, Euler characteristic χ, watertight, mean distance
from the data to the mesh relative to the bounding-box diagonal, and wall seconds.

Usage: tools/data_table.py [--bin target/release/stablesurf] [extra run flags...]
Example: cargo build --release && tools/data_table.py --degree 6 --depth 8
"""
import json
import os
import subprocess
import sys
import tempfile
import time

here = os.path.dirname(os.path.abspath(__file__))
root = os.path.dirname(here)
data = os.path.join(root, "..", "shared", "data")
args = sys.argv[1:]
binary = os.path.join(root, "target", "release", "stablesurf")
if args[:1] == ["--bin"]:
    binary, args = args[1], args[2:]

files = sorted(f for f in os.listdir(data) if f.endswith((".ply", ".obj", ".stl", ".xyz")))
print("| file | points | normals | degree | κ | bounded | components | χ | watertight | mean dist / diag | seconds |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
with tempfile.TemporaryDirectory() as tmp:
    for f in files:
        out = os.path.join(tmp, f)
        t = time.time()
        p = subprocess.run([binary, "run", os.path.join(data, f), "-o", out, "--no-cache", "-q",
                            "--mode", "global", "--formats", "json"] + args, capture_output=True, text=True)
        secs = time.time() - t
        if p.returncode != 0:
            msg = p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "failed"
            print(f"| {f} | | | | | | | | | error: {msg} | {secs:.2f} |")
            continue
        r = json.load(open(os.path.join(out, "report.json")))
        st = {s["stage"]: s for s in r["stages"]}
        fit = r["fit"]["fit"] or {}
        d = r["fit"]["diagnostics"] or {}
        print(f"| {f} | {st['import']['figures']['points']} | {st['normals']['figures']['source']} "
              f"| {r['stages'][2]['figures']['degree']} | {fit.get('kappa', 0):.2g} | {d.get('bounded')} "
              f"| {r['mesh']['components']} | {r['mesh']['euler_characteristic']} | {r['mesh']['watertight']} "
              f"| {r['accuracy']['mean_relative']:.2e} | {secs:.2f} |")
