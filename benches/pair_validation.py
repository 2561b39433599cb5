#!/usr/bin/python3
"""`rig match pair` on the independent validation scenes: is its sigma.tif an honest error bar?

For one overlapping pair of each scene (../shared/validation/scenes/*, or tests/data/validation
in the repository) the script, independently of the rig:

1. epipolar-rectifies the pair from the scene's exact orientations (scene.json): a common
   rotation whose x axis is the base (Fusiello, Trucco & Verri 2000, "A compact algorithm for
   rectification of stereo pairs", Machine Vision and Applications 12: 16-22), the original
   focal length and pixel size, each photo resampled through its homography
   H = K R_i^T R_n K^-1 with Keys' (1981) cubic convolution (a = -0.5); pixels whose 4 x 4
   neighbourhood leaves the photo or touches a ray that missed the DEM (DN 0) are NaN;
2. computes the true disparity of each left rectified pixel centre: its ray is intersected with
   the truth DEM (bilinear between posts, as the renderer's surface) by marching down from the
   highest post and bisecting, the point is projected into the right rectified camera, and
   d = col_left - col_right (rig's and Middlebury's convention, pixel centres at integers).
   The point is occluded for the right photo when the segment from it to the right camera's
   centre passes below the surface;
3. runs `rig match pair LEFT RIGHT --disparity MIN MAX --out DIR --json` (MIN/MAX from the truth,
   3 px wider) for each mode asked (default; --subpixel lsm; ...) and reports, over the pixels
   with a truth, seen by both photos, more than 4 px from the border: coverage, bad-2, the RMSE
   of the pixels within 2 px of the truth, and on them RMS(true error / sigma) and the share of
   errors within 2 sigma (goal: 0.8-1.25 and 50-98 %).

Needs numpy and GDAL's Python bindings (/usr/bin/python3; apt-get install python3-gdal).
Run from the checkout with a release build:

    /usr/bin/python3 benches/pair_validation.py --rig target/release/rig --work /tmp/pairval
    #  --scenes DIR (default ../shared/validation/scenes, else tests/data/validation/scenes)
    #  --only lidar-banks  --pair 1 2  --modes default lsm  --json  --keep (leave the rasters)
    #  --export DIR: also write the rectified pairs there as 8-bit-free float TIFFs + truth
"""

import argparse
import json
import os
import subprocess
import sys

import numpy as np
from osgeo import gdal

gdal.UseExceptions()

MODES = {
    "default": [],
    "lsm": ["--subpixel", "lsm"],
    "none": ["--filter", "none"],
    "none-lsm": ["--filter", "none", "--subpixel", "lsm"],
}


def rot(omega, phi, kappa):
    """R = R_omega R_phi R_kappa, image -> object (the scenes' convention)."""
    cw, sw, cp, sp, ck, sk = (np.cos(omega), np.sin(omega), np.cos(phi), np.sin(phi),
                              np.cos(kappa), np.sin(kappa))
    rw = np.array([[1, 0, 0], [0, cw, -sw], [0, sw, cw]])
    rp = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rk = np.array([[ck, -sk, 0], [sk, ck, 0], [0, 0, 1]])
    return rw @ rp @ rk


class Camera:
    def __init__(self, ph):
        i, e = ph["interior"], ph["exterior"]
        self.c = i["focal_mm"]
        self.p = i["pixel_size_um"] / 1000.0
        self.W, self.H = i["image_size_px"]
        self.pp = np.array(i["principal_point_mm"], float)
        self.C = np.array([e["X0"], e["Y0"], e["Z0"]], float)
        self.R = rot(e["omega"], e["phi"], e["kappa"])
        self.file = ph["file"]


def keys_weights(t):
    """Keys (1981) cubic convolution weights (a = -0.5) for taps -1, 0, 1, 2 at fraction t."""
    a = -0.5
    def k(x):
        x = np.abs(x)
        return np.where(x <= 1, (a + 2) * x ** 3 - (a + 3) * x ** 2 + 1,
                        np.where(x < 2, a * x ** 3 - 5 * a * x ** 2 + 8 * a * x - 4 * a, 0.0))
    return [k(t + 1), k(t), k(1 - t), k(2 - t)]


def bicubic(img, col, row):
    """img sampled at (col, row) (pixel centres at integers); NaN where a tap is outside or
    NaN."""
    H, W = img.shape
    c0, r0 = np.floor(col), np.floor(row)
    tc, tr = col - c0, row - r0
    c0, r0 = c0.astype(np.int64), r0.astype(np.int64)
    ok = (c0 >= 1) & (c0 <= W - 3) & (r0 >= 1) & (r0 <= H - 3)
    c0, r0 = np.where(ok, c0, 1), np.where(ok, r0, 1)
    wc, wr = keys_weights(tc), keys_weights(tr)
    out = np.zeros(col.shape)
    for j in range(4):
        acc = np.zeros(col.shape)
        for i in range(4):
            acc += wc[i] * img[r0 + j - 1, c0 + i - 1]
        out += wr[j] * acc
    return np.where(ok, out, np.nan)


class Dem:
    def __init__(self, path, e0, n0):
        ds = gdal.Open(path)
        gt = ds.GetGeoTransform()
        self.z = ds.GetRasterBand(1).ReadAsArray().astype(np.float64)
        nd = ds.GetRasterBand(1).GetNoDataValue()
        if nd is not None:
            self.z[self.z == nd] = np.nan
        # Post (i, j) at pixel centre: X = x0 + (i + 0.5) dx (local: E - E0).
        self.x0, self.dx = gt[0] - e0, gt[1]
        self.y0, self.dy = gt[3] - n0, gt[5]
        self.rows, self.cols = self.z.shape
        self.zmin, self.zmax = np.nanmin(self.z), np.nanmax(self.z)

    def at(self, X, Y):
        """Bilinear between posts; NaN outside the posts."""
        fi = (X - self.x0) / self.dx - 0.5
        fj = (Y - self.y0) / self.dy - 0.5
        i0, j0 = np.floor(fi), np.floor(fj)
        ok = (i0 >= 0) & (i0 <= self.cols - 2) & (j0 >= 0) & (j0 <= self.rows - 2)
        i0 = np.where(ok, i0, 0).astype(np.int64)
        j0 = np.where(ok, j0, 0).astype(np.int64)
        ti, tj = fi - i0, fj - j0
        z = self.z
        v = ((1 - ti) * (1 - tj) * z[j0, i0] + ti * (1 - tj) * z[j0, i0 + 1]
             + (1 - ti) * tj * z[j0 + 1, i0] + ti * tj * z[j0 + 1, i0 + 1])
        return np.where(ok, v, np.nan)

    def step(self):
        return 0.25 * min(abs(self.dx), abs(self.dy))


def intersect(dem, C, dirs):
    """First intersection of rays C + s·dirs (dirs pointing down) with the DEM; NaN where none
    (inside the posts)."""
    dz = dirs[..., 2]
    horiz = np.hypot(dirs[..., 0], dirs[..., 1]) / np.maximum(-dz, 1e-9)
    # Height steps that move the ray at most a quarter post sideways.
    zstep = dem.step() / max(np.nanmax(horiz), 1e-3)
    ztop, zbot = dem.zmax + 1e-6, dem.zmin - 1e-6
    n = int(np.ceil((ztop - zbot) / zstep)) + 1
    zs = np.linspace(ztop, zbot, n)

    def point(z):
        s = (z - C[2]) / dz
        return C[0] + s * dirs[..., 0], C[1] + s * dirs[..., 1]

    found = np.zeros(dz.shape, bool)
    lo = np.full(dz.shape, np.nan)   # ray height above the surface (f > 0)
    hi = np.full(dz.shape, np.nan)   # below (f <= 0)
    prev_z = np.full(dz.shape, ztop)
    prev_f = None
    for z in zs:
        X, Y = point(z)
        # Outside the posts the ray counts as above the surface.
        f = np.nan_to_num(z - dem.at(X, Y), nan=1.0)
        if prev_f is not None:
            hit = (~found) & (prev_f > 0) & (f <= 0)
            lo = np.where(hit, prev_z, lo)
            hi = np.where(hit, z, hi)
            found |= hit
        prev_f = f
        prev_z = np.full(dz.shape, z)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        X, Y = point(mid)
        f = mid - dem.at(X, Y)
        above = f > 0
        lo = np.where(above, mid, lo)
        hi = np.where(above, hi, mid)
    z = 0.5 * (lo + hi)
    X, Y = point(z)
    out = np.stack([X, Y, z], -1)
    out[~found] = np.nan
    return out


def rectify_pair(scene_dir, i1, i2):
    sj = json.load(open(os.path.join(scene_dir, "scene.json")))
    os_ = sj["object_system"]
    photos = {p["id"]: p for p in sj["photos"]}
    cam1, cam2 = Camera(photos[i1]), Camera(photos[i2])
    e0, n0 = (os_.get("E0", 0.0), os_.get("N0", 0.0))
    dem = Dem(os.path.join(scene_dir, sj["truth_dem"]["file"]), e0, n0)
    # The common rotation (image -> object): x along the base, z the mean of the two z axes
    # made orthogonal to it, y = z × x.
    r1 = cam2.C - cam1.C
    r1 /= np.linalg.norm(r1)
    zm = cam1.R[:, 2] + cam2.R[:, 2]
    r3 = zm - r1 * (zm @ r1)
    r3 /= np.linalg.norm(r3)
    r2 = np.cross(r3, r1)
    Rn = np.stack([r1, r2, r3], 1)
    f, p = cam1.c, cam1.p

    def to_rect(cam, col, row):
        """Original pixel -> rectified photo (x, y) mm."""
        x = (col - (cam.W - 1) / 2) * cam.p - cam.pp[0]
        y = ((cam.H - 1) / 2 - row) * cam.p - cam.pp[1]
        v = Rn.T @ cam.R @ np.stack([x, y, -cam.c * np.ones_like(x)])
        return -f * v[0] / v[2], -f * v[1] / v[2]

    def from_rect(cam, xr, yr):
        """Rectified photo (x, y) mm -> original pixel (col, row)."""
        v = np.tensordot(cam.R.T @ Rn, np.stack([xr, yr, -f * np.ones_like(xr)]), 1)
        x = -cam.c * v[0] / v[2] + cam.pp[0]
        y = -cam.c * v[1] / v[2] + cam.pp[1]
        return x / cam.p + (cam.W - 1) / 2, (cam.H - 1) / 2 - y / cam.p

    # Each rectified photo covers its original's corners; the rows are common.
    def bbox(cam):
        cc = np.array([0, cam.W - 1, 0, cam.W - 1, (cam.W - 1) / 2], float)
        rr = np.array([0, 0, cam.H - 1, cam.H - 1, (cam.H - 1) / 2], float)
        x, y = to_rect(cam, cc, rr)
        return x.min(), x.max(), y.min(), y.max()

    b1, b2 = bbox(cam1), bbox(cam2)
    ytop, ybot = min(b1[3], b2[3]), max(b1[2], b2[2])
    rows = int(np.floor((ytop - ybot) / p)) + 1
    # Rectified pixel (col, row) -> (x, y) = (x0 + col·p, ytop - row·p).
    x0_1, x0_2 = b1[0], b2[0]
    cols1 = int(np.floor((b1[1] - b1[0]) / p)) + 1
    cols2 = int(np.floor((b2[1] - b2[0]) / p)) + 1

    def resample(cam, x0, cols):
        img = read_tif(os.path.join(scene_dir, cam.file))
        img[img == 0] = np.nan   # a ray missed the DEM
        cc, rr = np.meshgrid(np.arange(cols), np.arange(rows))
        oc, orow = from_rect(cam, x0 + cc * p, ytop - rr * p)
        return bicubic(img, oc, orow).astype(np.float32)

    left = resample(cam1, x0_1, cols1)
    right = resample(cam2, x0_2, cols2)

    # Truth: each left pixel centre's ray against the DEM.
    cc, rr = np.meshgrid(np.arange(cols1), np.arange(rows))
    xr, yr = x0_1 + cc * p, ytop - rr * p
    dirs = np.moveaxis(np.tensordot(Rn, np.stack([xr, yr, -f * np.ones_like(xr)]), 1), 0, -1)
    P = intersect(dem, cam1.C, dirs)
    v2 = np.tensordot(P - cam2.C, Rn, 1)   # Rn^T (P - C2)
    x2 = -f * v2[..., 0] / v2[..., 2]
    col2 = (x2 - x0_2) / p
    disp = cc - col2
    # Seen by the right camera: the segment P -> C2 stays above the surface (from 1 % of the
    # way, so as not to meet the surface at P itself).
    seen = np.isfinite(disp)
    for s in np.linspace(0.01, 0.6, 120):
        Q = P + s * (cam2.C - P)
        z = dem.at(Q[..., 0], Q[..., 1])
        seen &= ~(Q[..., 2] < z - 1e-6)
    seen &= (col2 >= 0) & (col2 <= cols2 - 1)
    info = dict(rows=rows, cols_left=cols1, cols_right=cols2, base_m=float(np.linalg.norm(cam2.C - cam1.C)),
                x0_left_mm=float(x0_1), x0_right_mm=float(x0_2), focal_mm=f, pixel_mm=p,
                photos=[cam1.file, cam2.file])
    return left, right, disp.astype(np.float32), seen, info


def write_tif(path, a):
    drv = gdal.GetDriverByName("GTiff")
    ds = drv.Create(path, a.shape[1], a.shape[0], 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).WriteArray(a.astype(np.float32))
    ds = None


def read_tif(path):
    ds = gdal.Open(path)   # kept while the band is read (GDAL 3.6 crashes otherwise)
    return ds.GetRasterBand(1).ReadAsArray().astype(np.float64)


def figures(d, s, truth, seen, border=4):
    b = border
    sl = (slice(b, -b), slice(b, -b))
    d, s, t, n = d[sl], s[sl], truth[sl], seen[sl]
    ok = n & np.isfinite(t)
    err = d - t
    good = ok & np.isfinite(d) & (np.abs(err) <= 2)
    out = dict(pixels=int(ok.sum()), coverage_percent=100.0 * float((ok & np.isfinite(d)).sum()) / max(int(ok.sum()), 1),
               bad2_percent=100.0 * float((ok & ~(np.isfinite(d) & (np.abs(err) <= 2))).sum()) / max(int(ok.sum()), 1))
    g = good & np.isfinite(s) & (s > 0)
    if g.any():
        e = err[g]
        r = e / s[g]
        out.update(rmse_px=float(np.sqrt(np.mean(e ** 2))), mean_error_px=float(e.mean()),
                   rms_error_over_sigma=float(np.sqrt(np.mean(r ** 2))),
                   within_2_sigma_percent=100.0 * float(np.mean(np.abs(r) < 2)),
                   median_sigma_px=float(np.median(s[g])), rms_sigma_px=float(np.sqrt(np.mean(s[g] ** 2))),
                   matched_within_2px=int(g.sum()))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    here = os.path.dirname(os.path.abspath(__file__))
    repo = os.path.dirname(here)
    default_scenes = os.path.join(repo, "..", "shared", "validation", "scenes")
    if not os.path.isdir(default_scenes):
        default_scenes = os.path.join(repo, "tests", "data", "validation", "scenes")
    ap.add_argument("--rig", default=os.path.join(repo, "target", "release", "rig"))
    ap.add_argument("--scenes", default=default_scenes)
    ap.add_argument("--work", default="/tmp/pair_validation")
    ap.add_argument("--only", nargs="*", default=["lidar-banks", "jacksboro-wide", "jacksboro-close"])
    ap.add_argument("--pair", nargs=2, type=int, default=[1, 2])
    ap.add_argument("--modes", nargs="*", default=["default", "lsm"], choices=list(MODES))
    ap.add_argument("--rig-args", default="", help="extra flags for every rig run")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--prepare-only", action="store_true", help="rectify and write the truth, no rig runs")
    ap.add_argument("--export", help="write each rectified pair, its truth and mask here")
    a = ap.parse_args()
    results = {}
    for scene in a.only:
        sd = os.path.join(a.scenes, scene)
        wd = os.path.join(a.work, scene)
        os.makedirs(wd, exist_ok=True)
        left, right, truth, seen, info = rectify_pair(sd, *a.pair)
        lp, rp = os.path.join(wd, "left.tif"), os.path.join(wd, "right.tif")
        write_tif(lp, left)
        write_tif(rp, right)
        write_tif(os.path.join(wd, "truth.tif"), np.where(seen, truth, np.nan))
        if a.export:
            ed = os.path.join(a.export, scene)
            os.makedirs(ed, exist_ok=True)
            for name, arr in (("left.tif", left), ("right.tif", right),
                              ("truth.tif", np.where(seen, truth, np.nan))):
                write_tif(os.path.join(ed, name), arr)
            json.dump(info, open(os.path.join(ed, "rectification.json"), "w"), indent=1)
        tv = truth[seen & np.isfinite(truth)]
        dmin, dmax = int(np.floor(tv.min())) - 3, int(np.ceil(tv.max())) + 3
        info.update(disparity=[dmin, dmax], truth_pixels=int(tv.size))
        print(f"{scene}: photos {a.pair}, rectified {info['cols_left']}+{info['cols_right']} x {info['rows']}, "
              f"true disparity {tv.min():.1f} … {tv.max():.1f} px on {tv.size} seen pixels; --disparity {dmin} {dmax}",
              file=sys.stderr)
        json.dump(info, open(os.path.join(wd, "info.json"), "w"), indent=1)
        results[scene] = dict(rectification=info)
        for mode in ([] if a.prepare_only else a.modes):
            out = os.path.join(wd, f"out-{mode}")
            os.makedirs(out, exist_ok=True)
            for fn in os.listdir(out):
                os.remove(os.path.join(out, fn))
            cmd = [a.rig, "match", "pair", lp, rp, "--disparity", str(dmin), str(dmax), "--out", out,
                   "--json"] + MODES[mode] + a.rig_args.split()
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                print(f"  {mode}: FAILED ({r.returncode}): {r.stderr.strip()}", file=sys.stderr)
                results[scene][mode] = dict(error=r.stderr.strip())
                continue
            d = read_tif(os.path.join(out, "disparity.tif"))
            s = read_tif(os.path.join(out, "sigma.tif"))
            fg = figures(d, s, truth, seen)
            results[scene][mode] = fg
            if "rmse_px" in fg:
                print(f"  {mode:9s} coverage {fg['coverage_percent']:5.1f} %, bad-2 {fg['bad2_percent']:5.2f} %, "
                      f"RMSE {fg['rmse_px']:.3f} px, RMS(err/σ) {fg['rms_error_over_sigma']:.2f}, "
                      f"{fg['within_2_sigma_percent']:.1f} % within 2σ, median σ {fg['median_sigma_px']:.3f} px",
                      file=sys.stderr)
    if a.json:
        json.dump(results, sys.stdout, indent=1)
        print()


if __name__ == "__main__":
    main()
