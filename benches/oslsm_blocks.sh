#!/usr/bin/env bash
# The object-space matching on one simulated block with 2, 3, 4 and 6 photos, beside the MGCM
# and the sweep on the same block (issue: "more photos help"; "better than MGCM's on the same
# block"). Renders all six photos of the block over photo 1's area that all six see (both
# strips' triple overlap), with planted radiometry (gains 1, 1.2, 0.85, 1.1, 0.9, 1.15;
# offsets 0, -3000, +4000, -1500, +2000, +1000 grey values) and 150 grey values of noise, runs
# `rig dtm` with method "oslsm" on photos 1-2, 1-3, 1-4 and 1-6 (photo 1 the reference), and
# "mgcm" and "sweep" on photos 1-4, and prints each DEM's RMSE against the true terrain (in metres and pixels of
# parallax), RMS(error/σ), the gains recovered, the whole run's time and the MGCM's points'
# own RMS. Accuracy, not speed, is the point here: the times are one run's.
#
#   benches/oslsm_blocks.sh [RIG]      (default: target/release/rig)
set -euo pipefail
rig=${1:-target/release/rig}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$rig" sim scene --seed 3 --area 78,-68,88,-58 --photos 6 --truth-cell-m 2 \
  --gains 1,1.2,0.85,1.1,0.9,1.15 --offsets 0,-3000,4000,-1500,2000,1000 --noise-dn 150 \
  --out "$work/scene" >/dev/null 2>&1
python3 - "$work/scene" <<'PY'
import sys
d = sys.argv[1]
t = open(f"{d}/block.toml").read()
head, *parts = t.split("\n[[photo]]")
def project(name, ids, method):
    out = head
    for p in parts:
        i = int(p.split('id = "')[1].split('"')[0])
        ph, rest = (p.split("\n[dem]", 1) + [""])[:2]
        rest = "\n[dem]" + rest if rest else ""
        if i in ids:
            out += "\n[[photo]]" + ph
        out += rest
    sec = "" if method == "sweep" else f'\n\n[matching.{method}]\nreference = "1"\n#'
    out = out.replace('method = "sweep"', f'method = "{method}"{sec}')
    open(f"{d}/{name}.toml", "w").write(out)
project("oslsm2", [1, 2], "oslsm")
project("oslsm3", [1, 2, 3], "oslsm")
project("oslsm4", [1, 2, 3, 4], "oslsm")
project("oslsm6", [1, 2, 3, 4, 5, 6], "oslsm")
project("mgcm4", [1, 2, 3, 4], "mgcm")
project("sweep4", [1, 2, 3, 4], "sweep")
PY
for n in oslsm2 oslsm3 oslsm4 oslsm6 mgcm4 sweep4; do
  s=$(date +%s.%N)
  "$rig" dtm "$work/scene/$n.toml" --json --out "$work/$n" > "$work/$n.json" 2>/dev/null
  e=$(date +%s.%N)
  echo "$e - $s" | bc > "$work/$n.wall"
done
python3 - "$work" <<'PY'
import json, sys
w = sys.argv[1]
for n in ["oslsm2", "oslsm3", "oslsm4", "oslsm6", "mgcm4", "sweep4"]:
    r = json.load(open(f"{w}/{n}.json"))
    wall = float(open(f"{w}/{n}.wall").read())
    c, s = r["comparison"], r.get("sigma_vs_reference") or {}
    mpp = r.get("m_per_px")
    px = f" = {c['rmse_m'] / mpp:.3f} px of parallax" if mpp else ""
    line = f"{n:7s}: DEM RMSE {c['rmse_m']:.3f} m{px} over {c['nodes']} nodes, RMS(error/σ) {s.get('ratio', float('nan')):.2f}, {wall:5.1f} s"
    if "radiometry" in r:
        line += ", gains " + " ".join(f"{g['id']}: {g['gain_median']:.4f}" for g in r["radiometry"])
    if "accuracy" in r and r["accuracy"]:
        a = r["accuracy"]["versions"][0]
        line += f"; its {r['kept']} points' RMS {a['rms_m']:.3f} m = {a['rms_m'] / mpp:.3f} px"
    print(line)
PY
