#!/usr/bin/env python3
"""Soak test of stablesurf under load: several processes run many small reconstructions at once on
one cache with a small size limit, some killed at random moments and left unreaped (zombies, as in
a container whose first process does not reap), some aimed at a folder another run is writing.

Afterwards it checks what the reliability promises say:
  - every cache entry verifies (`stablesurf cache verify`) and the entries' bytes are under the limit;
  - no staging folder or temporary name is left, in the cache or any output folder, once a run has
    completed into each folder (the promise is that the next run finishes or removes a killed
    run's debris);
  - every output folder holds exactly the files of a clean run with the same settings (report.json
    aside: it holds timings);
  - a run refused because another live run was writing its folder exited 1 naming the folder.
It prints its figures (runs, completions, kills, refusals, hits, misses, evictions, size) and exits
1 when any check fails. Python standard library only.

Usage: tools/soak.py [--bin target/release/stablesurf] [--procs 4] [--runs 25] [--limit 3MB]
                     [--seed 2026] [--work DIR]
"""

import argparse
import json
import math
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# Small global fits: each run takes a fraction of a second, so kills land in every stage.
SETTINGS = {
    "a": ["--mode", "global", "--degree", "4", "--depth", "5"],
    "b": ["--mode", "global", "--degree", "4", "--depth", "6"],
}
FORMATS = ["--formats", "glb,ply,png,json", "--slice-count", "2", "--slice-resolution", "16"]
# Output folders per (input, settings): runs of the same folder use the same settings, so the
# folder's final set is known; two slots, so runs collide on folders.
SLOTS = 2


def write_inputs(folder: Path, count: int, rng: random.Random) -> list:
    """Ellipsoids and tori as XYZ points with exact normals, 600 to 1,400 points each."""
    paths = []
    for i in range(count):
        n = rng.randrange(600, 1400)
        a, b, c = (rng.uniform(0.7, 1.6) for _ in range(3))
        torus = i % 2 == 1
        lines = []
        golden = math.pi * (3 - math.sqrt(5))
        for k in range(n):
            if torus:
                u, v = 2 * math.pi * k / n * 37, 2 * math.pi * ((k * golden) % 1.0)
                big, small = 1.5 * a, 0.5 * c
                x = (big + small * math.cos(v)) * math.cos(u)
                y = (big + small * math.cos(v)) * math.sin(u)
                z = small * math.sin(v)
                nx, ny, nz = math.cos(v) * math.cos(u), math.cos(v) * math.sin(u), math.sin(v)
            else:
                z0 = 1 - 2 * (k + 0.5) / n
                r = math.sqrt(1 - z0 * z0)
                t = golden * k
                ux, uy, uz = r * math.cos(t), r * math.sin(t), z0
                x, y, z = a * ux, b * uy, c * uz
                nx, ny, nz = ux / a, uy / b, uz / c
                norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                nx, ny, nz = nx / norm, ny / norm, nz / norm
            lines.append(f"{x:.6f} {y:.6f} {z:.6f} {nx:.6f} {ny:.6f} {nz:.6f}")
        path = folder / f"shape{i}.xyz"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


def command(binary: Path, source: Path, out: Path, cache, settings: str, limit: str) -> list:
    cmd = [str(binary), "run", str(source), "-o", str(out), *SETTINGS[settings], *FORMATS]
    if cache is None:
        return cmd + ["--no-cache"]
    return cmd + ["--cache-dir", str(cache), "--cache-max-size", limit]


def ended_whole(pid: int, timeout: float = 10.0) -> None:
    """Waits (at most TIMEOUT s) until the unreaped process PID is a zombie with no thread left."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        try:
            stat = Path(f"/proc/{pid}/stat").read_text()
            threads = len(list(Path(f"/proc/{pid}/task").iterdir()))
        except OSError:
            return
        if stat[stat.rfind(")") + 2] == "Z" and threads == 1:
            return
        time.sleep(0.01)


def hidden_names(folder: Path) -> list:
    return sorted(str(p) for p in folder.rglob(".*")) if folder.exists() else []


def outputs(folder: Path) -> dict:
    """Every file under folder but report.json, with its bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "report.json"
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default=str(ROOT / "target/release/stablesurf"))
    ap.add_argument("--procs", type=int, default=4, help="processes running at once")
    ap.add_argument("--runs", type=int, default=25, help="runs per process")
    ap.add_argument("--limit", default="3MB", help="the cache's size limit")
    ap.add_argument("--inputs", type=int, default=4, help="different inputs")
    ap.add_argument("--kill-share", type=float, default=0.3, help="share of runs killed")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--work", help="working folder (default: a new temporary folder, removed after)")
    args = ap.parse_args()
    binary = Path(args.bin).resolve()
    if not os.access(binary, os.X_OK):
        print(f"soak: {binary} is not an executable file (build it: cargo build --release)", file=sys.stderr)
        return 2
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="stablesurf-soak-"))
    if work.exists() and any(work.iterdir()) and args.work:
        print(f"soak: {work} is not empty; give a new or empty folder", file=sys.stderr)
        return 2
    work.mkdir(parents=True, exist_ok=True)
    start = time.time()
    rng = random.Random(args.seed)
    inputs = write_inputs(work, args.inputs, rng)
    cache = work / "cache"
    # Clean references: one run per (input, settings) without the cache.
    combos = [(i, s) for i in range(len(inputs)) for s in SETTINGS]
    reference = {}
    for i, s in combos:
        ref = work / "ref" / f"{i}{s}"
        done = subprocess.run(command(binary, inputs[i], ref, None, s, args.limit),
                              capture_output=True, text=True)
        if done.returncode != 0:
            print(f"soak: the clean run of input {i}, settings {s} failed:\n{done.stderr}", file=sys.stderr)
            return 1
        reference[(i, s)] = outputs(ref)

    counts = {"runs": 0, "completed": 0, "killed": 0, "refused": 0, "failed": 0}
    failures = []
    zombies = []
    lock = threading.Lock()

    def worker(seed: int) -> None:
        wrng = random.Random(seed)
        for _ in range(args.runs):
            i, s = wrng.choice(combos)
            out = work / "out" / f"{i}{s}-{wrng.randrange(SLOTS)}"
            kill_after = wrng.uniform(0.01, 0.4) if wrng.random() < args.kill_share else None
            proc = subprocess.Popen(command(binary, inputs[i], out, cache, s, args.limit),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            if kill_after is not None:
                try:
                    proc.wait(timeout=kill_after)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    # Left unreaped: a zombie until the end, as under a PID 1 that does not reap.
                    with lock:
                        counts["runs"] += 1
                        counts["killed"] += 1
                        zombies.append(proc)
                    continue
            _, err = proc.communicate()
            with lock:
                counts["runs"] += 1
                if proc.returncode == 0:
                    counts["completed"] += 1
                elif proc.returncode == 1 and "another stablesurf run" in err and str(out) in err:
                    counts["refused"] += 1
                else:
                    counts["failed"] += 1
                    failures.append(f"run into {out} exited {proc.returncode}: {err.strip()[-400:]}")

    threads = [threading.Thread(target=worker, args=(args.seed * 1000 + p,)) for p in range(args.procs)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    soak_seconds = time.time() - start

    # The killed runs' main threads turn zombie before their other threads have exited, and those
    # hold the output folder's lock for a few milliseconds more: wait until each has ended whole.
    for z in zombies:
        ended_whole(z.pid)
    # One completing run into every folder used: it finishes or removes the killed runs' debris.
    used = sorted((work / "out").iterdir()) if (work / "out").exists() else []
    for out in used:
        i, s = int(out.name[:-3]), out.name[-3]
        done = subprocess.run(command(binary, inputs[i], out, cache, s, args.limit),
                              capture_output=True, text=True)
        if done.returncode != 0:
            failures.append(f"the final run into {out} exited {done.returncode}: {done.stderr.strip()[-400:]}")
        elif outputs(out) != reference[(i, s)]:
            failures.append(f"{out} does not hold a clean run's files")
    for z in zombies:
        z.wait()

    info = json.loads(subprocess.run([str(binary), "cache", "info", "--json", "--cache-dir", str(cache),
                                      "--cache-max-size", args.limit],
                                     capture_output=True, text=True, check=True).stdout)
    verify = subprocess.run([str(binary), "cache", "verify", "--json", "--cache-dir", str(cache)],
                            capture_output=True, text=True)
    verified = json.loads(verify.stdout) if verify.stdout else {"valid": 0, "invalid": ["(no output)"]}
    if verify.returncode != 0 or verified["invalid"]:
        failures.append(f"cache entries fail verification: {verified['invalid'][:5]}")
    if info["bytes"] > info["max_size"]:
        failures.append(f"the cache holds {info['bytes']} bytes, over its limit {info['max_size']}")
    debris = hidden_names(cache) + [n for out in used for n in hidden_names(out)]
    if debris:
        failures.append(f"{len(debris)} staging or temporary names left: {debris[:5]}")
    if counts["completed"] == 0 or counts["killed"] == 0:
        failures.append("the soak neither completed nor killed runs: too few runs to test anything")

    rate = info["hit_rate"]
    print(f"soak: {args.procs} processes x {args.runs} runs on one cache limited to {args.limit} "
          f"({info['max_size']:,} bytes), {len(inputs)} inputs x {len(SETTINGS)} settings, "
          f"{SLOTS} output folders each, seed {args.seed}")
    print(f"soak: runs {counts['runs']}: completed {counts['completed']}, killed {counts['killed']} "
          f"(left as zombies until the end), refused {counts['refused']} (folder busy), "
          f"failed {counts['failed']}; {soak_seconds:.1f} s")
    print(f"soak: cache after {info['runs']} completed runs: {info['hits']} hits, {info['misses']} misses"
          f" (hit rate {'-' if rate is None else f'{100 * rate:.0f}%'}), {info['evicted_entries']} entries "
          f"evicted ({info['evicted_bytes']:,} bytes); {info['entries']} entries, {info['bytes']:,} bytes "
          f"of {info['max_size']:,}, {verified['valid']} verified")
    print(f"soak: {len(used)} output folders each hold a clean run's files: "
          f"{'yes' if not any('clean run' in f for f in failures) else 'no'}; "
          f"staging or temporary names left: {len(debris)}")
    for f in failures:
        print(f"soak: FAILED: {f}", file=sys.stderr)
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
