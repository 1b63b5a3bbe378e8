#!/usr/bin/env bash
# The cache's size limit over 20 different inputs: the models and raw scans of ../shared/data,
# bun.conf, and four thinnings of the bunny's vertices (every 2nd to 5th, bare XYZ points), each
# run into one cache limited to 50 MB; prints the cache's size after each run, verifies every
# entry, reruns the last input (every stage should be a hit) and prints `cache info`.
#
# Usage: tools/cache_limit.sh [--bin PATH] [--limit 50MB]    (work folder: a new temporary one)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bin="$root/target/release/stablesurf"
limit=50MB
while (($#)); do
    case "$1" in
        --bin) shift; bin="$(realpath "$1")" ;;
        --limit) shift; limit="$1" ;;
        *) echo "usage: tools/cache_limit.sh [--bin PATH] [--limit 50MB]" >&2; exit 2 ;;
    esac
    shift
done
[[ -x "$bin" ]] || { echo "cache_limit: $bin is not an executable file (cargo build --release)" >&2; exit 2; }
data="$root/../shared/data"
[[ -d "$data" ]] || { echo "cache_limit: $data is missing" >&2; exit 1; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
python3 - "$data/bunny_zipper.ply" "$work" <<'PY'
import sys
head, body = open(sys.argv[1], "rb").read().split(b"end_header\n", 1)
n = int(next(l for l in head.decode().splitlines() if l.startswith("element vertex")).split()[-1])
rows = body.decode(errors="ignore").splitlines()[:n]
for k in (2, 3, 4, 5):
    open(f"{sys.argv[2]}/thin{k}.xyz", "w").write("\n".join(" ".join(r.split()[:3]) for r in rows[::k]) + "\n")
PY
inputs=("$data"/{bunny_zipper.ply,duck.ply,fandisk.obj,fertility.ply,max_planck.obj,patella_vhf_left.ply,quadknot.obj,spot.obj,teapot.obj}
        "$data"/bunny-scans/{bun000.ply,bun090.ply,bun180.ply,bun270.ply,bun315.ply,top2.ply,bun.conf}
        "$work"/thin{2,3,4,5}.xyz)
cache="$work/cache"
i=0
for f in "${inputs[@]}"; do
    i=$((i + 1))
    "$bin" -q run "$f" -o "$work/out/$i" --cache-dir "$cache" --cache-max-size "$limit"
    "$bin" cache info --json --cache-dir "$cache" --cache-max-size "$limit" | python3 -c \
        "import json, sys; d = json.load(sys.stdin); print(f'after run $i ($(basename "$f")): {d[\"bytes\"]:,} bytes of {d[\"max_size\"]:,} in {d[\"entries\"]} entries, {d[\"evicted_entries\"]} evicted so far')"
done
"$bin" cache verify --cache-dir "$cache"
echo "rerun of the last input:"
"$bin" -v run "${inputs[-1]}" -o "$work/out/again" --cache-dir "$cache" --cache-max-size "$limit" 2>&1 \
    | grep -E "^stablesurf: (import|normals|fit|detail|polygonize|finish|export) " | cut -c1-40
"$bin" cache info --cache-dir "$cache" --cache-max-size "$limit"
