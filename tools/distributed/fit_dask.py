#!/usr/bin/env python3
"""Global fit of a scan split into chunk files, on a Dask cluster.

Takes chunk scan files (any format `stablesurf` reads; normals from the files or the normals
stage), gives `model.json` (and with `--mesh OUT_DIR` a mesh `OUT_DIR/mesh.ply`). It runs the
three passes of the moments protocol (docs/stages.md, "Scale") as Dask tasks, one task per
chunk and pass, each calling `stablesurf moments` on its chunk in a temporary folder and
returning the part file's bytes; the driver gathers them (so no shared file system is needed for
the parts), merges the frame with `stablesurf frame` between passes, and finally runs
`stablesurf fit --from-moments` (and `stablesurf mesh`) locally.

The workers need the chunk paths and the `stablesurf` binary (`--binary`) at the same paths as
the driver. Without `--scheduler`, a LocalCluster of two single-threaded worker processes runs
the tasks; with it, any running Dask scheduler does.

A fit from moments needs a fixed `--kappa` or the paper's κ rule (the stable rule checks the
zero set against the points); the default here is `--kappa auto --kappa-rule paper`.

Usage: tools/distributed/.venv/bin/python tools/distributed/fit_dask.py CHUNK... -o model.json
       [--scheduler ADDRESS] [--binary PATH] [--degree N] [--epsilon E] [--kappa K]
       [--kappa-rule RULE] [--normals SOURCE] [--threads N] [--mesh OUT_DIR]
Exit codes: 0 success, 1 a stablesurf step or a task failed (its message is printed).
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def moments_task(binary, global_flags, chunk, extra):
    """Runs `stablesurf GLOBAL moments CHUNK -o PART EXTRA...` in a temporary folder; returns the part's bytes."""
    with tempfile.TemporaryDirectory(prefix="stablesurf-moments-") as tmp:
        part = os.path.join(tmp, "part.moments")
        cmd = [binary, "-q", *global_flags, "moments", chunk, "-o", part, *extra]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip()}")
        with open(part, "rb") as f:
            return f.read()


def run(cmd):
    """Runs a local stablesurf step; returns stdout, or exits 1 with its message."""
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"fit_dask: {' '.join(cmd)} failed:\n{done.stderr.strip()}")
    return done.stdout.strip()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("chunks", nargs="+", metavar="CHUNK", help="chunk scan files")
    ap.add_argument("-o", "--output", required=True, help="output model.json")
    ap.add_argument("--scheduler", help="address of a running Dask scheduler (default: a LocalCluster of 2 workers)")
    default_binary = REPO / "target" / "release" / "stablesurf"
    ap.add_argument("--binary", default=str(default_binary) if default_binary.exists() else shutil.which("stablesurf"),
                    help="the stablesurf binary (default: target/release/stablesurf, else on PATH)")
    ap.add_argument("--degree", default="8")
    ap.add_argument("--epsilon", default="0.05")
    ap.add_argument("--kappa", default="auto")
    ap.add_argument("--kappa-rule", default="paper")
    ap.add_argument("--normals", default="auto", help="normals source of the moments passes")
    ap.add_argument("--threads", help="threads of each stablesurf moments task (-j)")
    ap.add_argument("--mesh", metavar="OUT_DIR", help="also mesh the model into OUT_DIR/mesh.ply")
    args = ap.parse_args()
    if not args.binary or not os.access(args.binary, os.X_OK):
        ap.error("no stablesurf binary: build it (cargo build --release) or pass --binary PATH")
    binary = os.path.abspath(args.binary)
    chunks = [os.path.abspath(c) for c in args.chunks]
    for c in chunks:
        if not os.path.isfile(c):
            ap.error(f"chunk {c} does not exist")

    from dask.distributed import Client, LocalCluster

    cluster = None
    if args.scheduler:
        client = Client(args.scheduler)
    else:
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    common = ["--normals", args.normals, "--degree", args.degree, "--epsilon", args.epsilon]
    global_flags = ["-j", args.threads] if args.threads else []
    try:
        with tempfile.TemporaryDirectory(prefix="stablesurf-dask-") as tmp:
            frame_arg = []
            for pass_no, flag in [(1, None), (2, "--center"), (3, "--frame")]:
                t = time.perf_counter()
                extra = common + ([flag, frame_arg] if flag else [])
                futures = [client.submit(moments_task, binary, global_flags, c, extra, pure=False) for c in chunks]
                try:
                    blobs = client.gather(futures)
                except RuntimeError as e:
                    sys.exit(f"fit_dask: pass {pass_no}: {e}")
                parts = []
                for k, blob in enumerate(blobs):
                    path = os.path.join(tmp, f"pass{pass_no}-{k}.moments")
                    with open(path, "wb") as f:
                        f.write(blob)
                    parts.append(path)
                print(f"fit_dask: pass {pass_no}: {len(parts)} chunks in {time.perf_counter() - t:.2f} s",
                      file=sys.stderr)
                if pass_no < 3:
                    frame_arg = run([binary, "frame", *parts])
            fit_cmd = [binary, "-q", "fit", "--from-moments", *parts, "-o", args.output,
                       "--degree", args.degree, "--epsilon", args.epsilon,
                       "--kappa", args.kappa, "--kappa-rule", args.kappa_rule]
            run(fit_cmd)
            print(f"fit_dask: wrote {args.output}", file=sys.stderr)
        if args.mesh:
            os.makedirs(args.mesh, exist_ok=True)
            mesh = os.path.join(args.mesh, "mesh.ply")
            run([binary, "-q", "mesh", args.output, "-o", mesh])
            print(f"fit_dask: wrote {mesh}", file=sys.stderr)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


if __name__ == "__main__":
    main()
