#!/usr/bin/env bash
# MGCM beside the sweep on the same simulated block (issue: "points per second reported in a
# benchmark beside the sweep on the same block"). Renders a 3-photo block, runs `rig dtm` with
# method "mgcm" and "sweep" on it (each REPEAT times, the median taken), and prints each
# method's points per second of its matching, its heights' accuracy against the true terrain
# and the ratio of the two rates. The rates are the runs' own (report.json: the MGCM's finest
# level) and over whole commands (the sweep's: its points over the whole run).
#
#   benches/mgcm_vs_sweep.sh [RIG] [REPEAT]      (defaults: target/release/rig, 3)
set -euo pipefail
rig=${1:-target/release/rig}
repeat=${2:-3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$rig" sim scene --seed 11 --area 40,-72,51,-61 --photos 3 --noise-dn 150 --truth-cell-m 2 \
  --out "$work/scene" >/dev/null 2>&1
for m in mgcm sweep; do
  sed "s/^method = \"sweep\".*/method = \"$m\"/" "$work/scene/block.toml" > "$work/scene/$m.toml"
  for i in $(seq "$repeat"); do
    rm -rf "$work/$m"
    s=$(date +%s.%N)
    "$rig" dtm "$work/scene/$m.toml" --json --out "$work/$m" > "$work/$m-$i.json" 2>/dev/null
    e=$(date +%s.%N)
    echo "$e - $s" | bc > "$work/$m-$i.wall"
  done
done
python3 - "$work" "$repeat" <<'PY'
import json, statistics, sys
work, n = sys.argv[1], int(sys.argv[2])
def load(m):
    rs = [json.load(open(f"{work}/{m}-{i}.json")) for i in range(1, n + 1)]
    walls = [float(open(f"{work}/{m}-{i}.wall").read()) for i in range(1, n + 1)]
    return rs, statistics.median(walls)
mg, mg_wall = load("mgcm")
sw, sw_wall = load("sweep")
mg_rate = statistics.median(r["points_per_second"] for r in mg)
mg_pts = mg[0]["kept"]
sw_pts = sw[0]["points"]
a = mg[0]["accuracy"]["versions"][0]
print(f"mgcm : {mg_pts:6d} points kept, {mg_rate:8.0f} points/s (finest level), whole run {mg_wall:5.1f} s, "
      f"points' RMS {a['rms_m']:.3f} m = {a['rms_m'] / mg[0]['m_per_px']:.3f} px of parallax")
c = sw[0]["comparison"]
print(f"sweep: {sw_pts:6d} points kept, {sw_pts / sw_wall:8.0f} points/s (whole run), whole run {sw_wall:5.1f} s, "
      f"DEM RMSE {c['rmse_m']:.3f} m")
print(f"ratio (mgcm points/s over the sweep's, whole runs): {(mg_pts / mg_wall) / (sw_pts / sw_wall):.3f}")
PY
