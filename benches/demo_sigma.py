#!/usr/bin/env python3
"""`rig demo`'s error bars over seeds (issue 37): RMS(true error / sigma) of its DEM against the
true DEM, the share within 2 sigma, and where the error comes from.

For each seed it runs `rig demo --seed N --out WORK/seed-N` (or reuses that folder with
--reuse) and prints, from the DEM and the demo's own truth (truth-dem.tif, points.csv):
- the report's ratio, share within 2 sigma and the orientations' sigma;
- the plane through the DEM's error (mean, tilts in m/km) and what is left about it;
- the plane through the control points' own ground error (their noisy z less the true DEM):
  a model resected from that control follows it.

    /usr/bin/python3 benches/demo_sigma.py --rig target/release/rig --work /tmp/demo-sigma --seeds 1 2 3

Needs numpy and GDAL's Python bindings (osgeo), as the system's python3 has them.
"""
import argparse, csv, json, os, subprocess

import numpy as np
from osgeo import gdal


def bilinear(path, x, y):
    ds = gdal.Open(path)
    g = ds.GetGeoTransform()
    z = ds.ReadAsArray().astype(float)
    c = (x - g[0]) / g[1] - 0.5
    r = (y - g[3]) / g[5] - 0.5
    c0 = np.clip(np.floor(c).astype(int), 0, z.shape[1] - 2)
    r0 = np.clip(np.floor(r).astype(int), 0, z.shape[0] - 2)
    fc, fr = c - c0, r - r0
    inside = (c >= 0) & (r >= 0) & (c <= z.shape[1] - 1) & (r <= z.shape[0] - 1)
    v = (z[r0, c0] * (1 - fc) * (1 - fr) + z[r0, c0 + 1] * fc * (1 - fr)
         + z[r0 + 1, c0] * (1 - fc) * fr + z[r0 + 1, c0 + 1] * fc * fr)
    return v, inside


def plane(x, y, e):
    """Mean, tilt along x and y (m/km) and the RMS left about the plane."""
    x = (x - x.mean()) / 1000.0
    y = (y - y.mean()) / 1000.0
    a = np.c_[np.ones_like(x), x, y]
    c, *_ = np.linalg.lstsq(a, e, rcond=None)
    return c, float(np.sqrt(((e - a @ c) ** 2).mean()))


def one(d):
    r = json.load(open(os.path.join(d, "dtm", "report.json")))
    s = r["sigma_vs_reference"]
    ds = gdal.Open(os.path.join(d, "dtm", "dem.tif"))
    g = ds.GetGeoTransform()
    z = ds.ReadAsArray().astype(float)
    xs, ys = np.meshgrid(g[0] + g[1] * (np.arange(z.shape[1]) + 0.5),
                         g[3] + g[5] * (np.arange(z.shape[0]) + 0.5))
    t, inside = bilinear(os.path.join(d, "truth-dem.tif"), xs, ys)
    ok = inside & (z > -9000)
    dem_plane, dem_left = plane(xs[ok], ys[ok], (z - t)[ok])
    gcp = {}
    with open(os.path.join(d, "points.csv")) as f:
        for row in csv.DictReader(f):
            if row["kind"] == "gcp":
                gcp[row["id"]] = (float(row["x"]), float(row["y"]), float(row["z"]))
    p = np.array(list(gcp.values()))
    tz, inside = bilinear(os.path.join(d, "truth-dem.tif"), p[:, 0], p[:, 1])
    gcp_plane, _ = plane(p[inside, 0], p[inside, 1], (p[:, 2] - tz)[inside])
    return {
        "ratio": s["ratio"],
        "within_2_sigma_percent": s["within_2_sigma_percent"],
        "orientation_sigma_m": r.get("orientation_sigma_m"),
        "dem_error": {"mean_m": dem_plane[0], "tilt_x_m_per_km": dem_plane[1],
                      "tilt_y_m_per_km": dem_plane[2], "rms_about_plane_m": dem_left},
        "control_error": {"mean_m": gcp_plane[0], "tilt_x_m_per_km": gcp_plane[1],
                          "tilt_y_m_per_km": gcp_plane[2]},
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rig", default="target/release/rig")
    ap.add_argument("--work", default="/tmp/demo-sigma")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--reuse", action="store_true", help="use WORK/seed-N when it has a model")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    out = {}
    for n in a.seeds:
        d = os.path.join(a.work, f"seed-{n}")
        if not (a.reuse and os.path.exists(os.path.join(d, "dtm", "report.json"))):
            subprocess.run([a.rig, "demo", "--seed", str(n), "--out", d], check=True,
                           stdout=subprocess.DEVNULL)
        out[n] = f = one(d)
        if not a.json:
            e, c = f["dem_error"], f["control_error"]
            print(f"seed {n}: RMS(err/σ) {f['ratio']:.2f}, {f['within_2_sigma_percent']:.1f} % within 2σ, "
                  f"orientations' σ {f['orientation_sigma_m']:.2f} m; DEM error mean {e['mean_m']:+.2f} m, "
                  f"tilt {e['tilt_x_m_per_km']:+.2f} / {e['tilt_y_m_per_km']:+.2f} m/km, {e['rms_about_plane_m']:.2f} m about it; "
                  f"control's error mean {c['mean_m']:+.2f} m, tilt {c['tilt_x_m_per_km']:+.2f} / {c['tilt_y_m_per_km']:+.2f} m/km")
    if a.json:
        print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
