#!/usr/bin/env python3
"""Rectified-pair matching: `rig match pair` against OpenCV's StereoBM and StereoSGBM.

The script renders its own rectified stereo pair (numpy only, with an exactly known disparity
and non-occlusion mask), runs the rig and the OpenCV peers on it, and prints one table: time,
throughput in pixel-candidates per second (width * height * number of disparities / seconds),
the rig's throughput over each peer's, bad-1 / bad-2 (percent of pixels off by more than 1 / 2
px, missing counted as bad) on non-occluded and on all pixels, percent invalid, and the RMSE of
the non-occluded pixels within 2 px of the truth.

OpenCV is a dependency of this benchmark only, never of the project. A throwaway venv:

    python3 -m venv /tmp/cvenv
    /tmp/cvenv/bin/pip install opencv-python-headless numpy pillow tifffile

Run from the checkout (the rig built with `cargo build --release`):

    /tmp/cvenv/bin/python benches/stereo_vs_opencv.py --rig target/release/rig --work /tmp/stereo

The rig is run as `RIG match pair LEFT RIGHT --disparity 0 63 --out DIR --json [RIG_ARGS]`; it
writes DIR/disparity.tif (float32, NaN where unmatched) and prints JSON with `seconds` (the
matching alone) and `candidates`. If it fails, its stderr is shown and the peers still run.
"""
import argparse, json, os, shlex, statistics, subprocess, sys, time
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np
import tifffile
from PIL import Image

NDISP = 64  # disparities 0..63, for every method
THREADS = 2


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ---------------------------------------------------------------- scene and rendering
@dataclass
class Plane:
    """A planar surface d(x, y) = a + b*x + c*y in left-image coordinates (a plane in space is
    a linear function in disparity space), present where support(x_left, y) is true."""
    a: float
    b: float
    c: float
    support: Callable
    tex: int  # which texture it carries (the roof's two halves share one)


def make_scene(W, H):
    box = lambda x0, x1, y0, y1: (lambda x, y: (x >= x0 * W) & (x <= x1 * W) & (y >= y0 * H) & (y <= y1 * H))
    cx, cy, r = 0.62 * W, 0.32 * H, 0.16 * H  # slanted disc: 40 +- 11.7 px
    yr, k = 0.75 * H, 14.0 / (0.15 * H)       # roof: ridge 56 px, eaves 42 px, + 0.004 x
    return [
        Plane(10.0, 16.0 / W, 4.0 / H, lambda x, y: np.ones(np.broadcast(x, y).shape, bool), 0),
        Plane(50.0, 0.0, 0.0, box(0.12, 0.34, 0.15, 0.50), 1),
        Plane(40 - 10 * cx / r + 6 * cy / r, 10 / r, -6 / r,
              lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 <= r * r, 2),
        Plane(56 - k * yr, 0.004, k, box(0.35, 0.82, 0.60, 0.75), 3),   # roof, far half
        Plane(56 + k * yr, 0.004, -k, box(0.35, 0.82, 0.75, 0.90), 3),  # roof, near half
        Plane(46.0, 0.0, 0.0, box(0.88, 0.905, 0.45, 0.97), 4),         # a thin post
    ]


def frontmost(scene, x, y, view):
    """The z-buffer: at view coordinates (x, y), the nearest surface (largest disparity).
    Returns its disparity, its index and the point's left-image x (the texture coordinate)."""
    best_d = np.full(np.broadcast(x, y).shape, -np.inf)
    best_k = np.full(best_d.shape, -1)
    best_xl = np.zeros(best_d.shape)
    for k, p in enumerate(scene):
        # left: x_l = x; right: x = x_l - d(x_l, y)  =>  x_l = (x + a + c*y) / (1 - b)
        xl = x + 0.0 * y if view == "left" else (x + p.a + p.c * y) / (1.0 - p.b)
        d = p.a + p.b * xl + p.c * y
        take = p.support(xl, y) & (d > best_d)
        best_d = np.where(take, d, best_d)
        best_k = np.where(take, k, best_k)
        best_xl = np.where(take, xl, best_xl)
    return best_d, best_k, best_xl


def fade(t):
    return t * t * t * (t * (t * 6 - 15) + 10)


def value_noise(lat, u, v):
    """Smoothly interpolated lattice noise at continuous lattice coordinates (u, v)."""
    i, j = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = fade(u - i), fade(v - j)
    h, w = lat.shape
    i0, i1, j0, j1 = i % w, (i + 1) % w, j % h, (j + 1) % h
    top = lat[j0, i0] * (1 - fu) + lat[j0, i1] * fu
    bot = lat[j1, i0] * (1 - fu) + lat[j1, i1] * fu
    return top * (1 - fv) + bot * fv


def make_textures(rng, n, W, H):
    """Per texture: a mean grey, octaves of lattice noise at 2..64 px (amplitude growing mildly
    with scale), and an envelope that damps the finer octaves to ~8 % in about a quarter of the
    surface: weakly textured patches."""
    out = []
    for t in range(n):
        octs = []
        n_lat = lambda s: int((W + H + 512) / s) + 4  # covers the rotated coordinates: no repeats
        for s in (2, 4, 8, 16, 32, 64):
            lat = rng.standard_normal((n_lat(s), n_lat(s)))
            th = rng.uniform(0, np.pi)  # each octave's lattice turned, against axis-aligned blocks
            octs.append((s, s ** 0.35, lat, np.cos(th) / s, np.sin(th) / s))
        env = rng.standard_normal((n_lat(90), n_lat(90)))
        out.append(dict(mean=rng.uniform(95, 160), octs=octs, env=env))
    return out


def texture(tx, x, y):
    x, y = x + 256.0, y + 256.0  # keep the lattice coordinates positive
    e = value_noise(tx["env"], x / 90, y / 90)
    env = 0.08 + 0.92 * np.clip((e + 0.6) / 0.8, 0, 1)
    fine = coarse = 0.0
    for s, amp, lat, c, si in tx["octs"]:
        nz = amp * value_noise(lat, c * x - si * y + lat.shape[1] / 2, si * x + c * y)
        if s <= 8:
            fine = fine + nz
        else:
            coarse = coarse + nz
    return tx["mean"] + 16.0 * env * fine + 9.0 * coarse


def render(scene, textures, W, H, view, ss):
    """Box-filtered supersampling: ss x ss sub-samples per pixel, each shaded by the frontmost
    surface of this view. Rows in bands to keep memory small."""
    img = np.zeros((H, W))
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for y0 in range(0, H, 64):
        ys = np.arange(y0, min(H, y0 + 64))
        Y = (ys[:, None] + offs[None, :]).reshape(-1, 1)   # (rows*ss, 1)
        X = (np.arange(W)[:, None] + offs[None, :]).reshape(1, -1)  # (1, W*ss)
        _, k, xl = frontmost(scene, X, Y, view)
        Yb = np.broadcast_to(Y, k.shape)
        shade = np.zeros(k.shape)
        for t in range(len(textures)):
            m = np.isin(k, [i for i, p in enumerate(scene) if p.tex == t])
            shade[m] = texture(textures[t], xl[m], Yb[m])
        img[ys] = shade.reshape(len(ys), ss, W, ss).mean(axis=(1, 3))
    return img


def sample_x(img, xs):
    """Catmull-Rom interpolation of each row of img at the columns xs (same shape as img)."""
    H, W = img.shape
    i = np.floor(xs).astype(np.int64)
    t = xs - i
    rows = np.arange(H)[:, None]
    p = [img[rows, np.clip(i + o, 0, W - 1)] for o in (-1, 0, 1, 2)]
    return p[1] + 0.5 * t * (p[2] - p[0] + t * (2 * p[0] - 5 * p[1] + 4 * p[2] - p[3]
                                                + t * (3 * (p[1] - p[2]) + p[3] - p[0])))


def render_pair(W, H, ss, sigma, seed, work):
    rng = np.random.default_rng(seed)
    scene = make_scene(W, H)
    textures = make_textures(rng, 1 + max(p.tex for p in scene), W, H)
    t0 = time.perf_counter()
    clean = {v: render(scene, textures, W, H, v, ss) for v in ("left", "right")}
    noisy = {v: np.clip(np.rint(clean[v] + rng.normal(0, sigma, (H, W))), 0, 255).astype(np.uint8)
             for v in clean}
    X, Y = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    gt, _, _ = frontmost(scene, X, Y, "left")
    xr = X - gt
    d_r, _, _ = frontmost(scene, xr, Y, "right")  # what the right view sees at x - d
    nonocc = (xr >= -0.5) & (xr <= W - 0.5) & (d_r <= gt + 1e-6)
    log(f"rendered {W}x{H}, {ss}x{ss} samples per pixel, in {time.perf_counter() - t0:.1f} s; "
        f"disparity {gt.min():.1f}..{gt.max():.1f} px, {100 * (1 - nonocc.mean()):.1f} % occluded")

    # Sanity: the left image against the right one sampled at x - d, on non-occluded pixels
    # well inside both images. With independent noise only, the mean |difference| would be
    # 2*sigma/sqrt(pi) (plus a little for the 8-bit rounding).
    ok = nonocc & (xr >= 2) & (xr <= W - 3)
    mad = np.abs(noisy["left"] - sample_x(noisy["right"].astype(float), xr))[ok].mean()
    mad0 = np.abs(clean["left"] - sample_x(clean["right"], xr))[ok].mean()
    expect = 2 * np.sqrt(sigma ** 2 + 1 / 12) / np.sqrt(np.pi)
    log(f"sanity: mean |left - right warped by gt| = {mad:.2f} grey levels on non-occluded "
        f"pixels (noise alone: {expect:.2f}; without noise: {mad0:.2f})")

    paths = {v: os.path.join(work, f"{v}.png") for v in ("left", "right")}
    for v in paths:
        Image.fromarray(noisy[v]).save(paths[v])
    tifffile.imwrite(os.path.join(work, "gt_disparity.tif"), gt.astype(np.float32))
    Image.fromarray((nonocc * 255).astype(np.uint8)).save(os.path.join(work, "gt_nonocc.png"))
    sanity = dict(mad=float(mad), mad_noise_only=float(expect), mad_without_noise=float(mad0))
    return noisy, paths, gt.astype(np.float32), nonocc, sanity


# ---------------------------------------------------------------- the methods
def opencv_peers(bm_block, hh):
    bm = cv2.StereoBM.create(numDisparities=NDISP, blockSize=bm_block)
    # As OpenCV's stereo_match sample: its x-Sobel prefilter (the default), cap 31.
    bm.setPreFilterType(cv2.StereoBM_PREFILTER_XSOBEL)
    bm.setPreFilterCap(31)
    bm.setTextureThreshold(10)
    bm.setUniquenessRatio(15)
    bm.setSpeckleWindowSize(100)
    bm.setSpeckleRange(32)
    bm.setDisp12MaxDiff(1)

    def sgbm(mode, bs=5):
        return cv2.StereoSGBM.create(minDisparity=0, numDisparities=NDISP, blockSize=bs,
                                     P1=8 * bs * bs, P2=32 * bs * bs, disp12MaxDiff=1,
                                     preFilterCap=63, uniquenessRatio=10, speckleWindowSize=100,
                                     speckleRange=32, mode=mode)
    peers = [(f"OpenCV StereoBM (block {bm_block})", bm),
             ("OpenCV SGBM (5 paths)", sgbm(cv2.StereoSGBM_MODE_SGBM)),
             ("OpenCV SGBM 3-way", sgbm(cv2.StereoSGBM_MODE_SGBM_3WAY))]
    if hh:
        peers.append(("OpenCV SGBM HH (8 paths)", sgbm(cv2.StereoSGBM_MODE_HH)))
    return peers


def run_peer(matcher, left, right, repeat):
    matcher.compute(left, right)  # warm-up, untimed
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        raw = matcher.compute(left, right)
        times.append(time.perf_counter() - t0)
    disp = raw.astype(np.float32) / 16.0  # fixed point, 4 fractional bits
    disp[raw < 0] = np.nan                # invalid: below minDisparity*16 (here 0)
    return disp, statistics.median(times)


def rig_cmd(rig, paths, out, rig_args):
    return [rig, "match", "pair", paths["left"], paths["right"], "--disparity", "0", str(NDISP - 1),
            "--out", out, "--json"] + shlex.split(rig_args)


def paired_ratio(cmd, matcher, left, right, n):
    """The throughput ratio rig / peer from n interleaved pairs of runs (rig, then peer): each
    pair's ratio is peer seconds / rig seconds, and the median and quartiles of the n ratios
    are reported. A machine whose speed drifts between the two blocks of separate timings
    (a VM's neighbours) moves both halves of a pair alike."""
    matcher.compute(left, right)  # warm-up, untimed
    ratios = []
    for _ in range(n):
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            return None
        try:
            rig_s = float(json.loads(p.stdout)["seconds"])
        except (ValueError, KeyError, TypeError):
            return None
        t0 = time.perf_counter()
        matcher.compute(left, right)
        ratios.append((time.perf_counter() - t0) / rig_s)
    q = statistics.quantiles(ratios, n=4) if len(ratios) >= 2 else [ratios[0]] * 3
    return dict(pairs=n, median=statistics.median(ratios), q1=q[0], q3=q[2])


def run_rig(rig, paths, work, rig_args, repeat, shape):
    out = os.path.join(work, "rig_out")
    cmd = rig_cmd(rig, paths, out, rig_args)
    log("rig:", shlex.join(cmd))
    secs, walls, info = [], [], {}
    for _ in range(repeat):
        tif = os.path.join(out, "disparity.tif")
        if os.path.exists(tif):
            os.remove(tif)  # never read a stale result
        t0 = time.perf_counter()
        try:
            p = subprocess.run(cmd, capture_output=True, text=True)
        except OSError as e:
            return None, dict(error=f"cannot run the rig: {e}")
        walls.append(time.perf_counter() - t0)
        if p.returncode != 0:
            log(f"rig failed (exit {p.returncode}); its stderr:\n{p.stderr.rstrip()}")
            last = (p.stderr.strip().splitlines() or [""])[-1][:100]
            return None, dict(error=f"exit {p.returncode}: {last}", stderr=p.stderr[-4000:])
        try:
            info = json.loads(p.stdout)
        except ValueError:
            lines = [l for l in p.stdout.splitlines() if l.strip()]
            try:
                info = json.loads(lines[-1])
            except (ValueError, IndexError):
                return None, dict(error="stdout is not JSON", stdout=p.stdout[-2000:])
        if "seconds" in info:
            secs.append(float(info["seconds"]))
    try:
        disp = tifffile.imread(os.path.join(out, "disparity.tif")).astype(np.float32)
    except (OSError, ValueError) as e:
        return None, dict(error=f"no readable disparity.tif: {e}")
    if disp.shape != shape:
        return None, dict(error=f"disparity.tif is {disp.shape}, expected {shape}")
    try:
        sigma = tifffile.imread(os.path.join(out, "sigma.tif")).astype(np.float32)
    except (OSError, ValueError):
        sigma = None
    return disp, dict(sigma=sigma if sigma is not None and sigma.shape == shape else None,
                      rig_seconds=statistics.median(secs) if secs else None,
                      wall_seconds=statistics.median(walls), candidates=info.get("candidates"),
                      rig_json=info)


def sigma_check(disp, sigma, gt, nonocc, border=4):
    """Whether the rig's sigma.tif is an honest error bar: on the non-occluded pixels within
    2 px of the truth (the sub-pixel regime), RMS(true error / sigma) (1 when honest) and the
    share of errors within 2 sigma (95 % for a Gaussian)."""
    b = border
    d, s, g, n = disp[b:-b, b:-b], sigma[b:-b, b:-b], gt[b:-b, b:-b], nonocc[b:-b, b:-b]
    m = n & np.isfinite(d) & np.isfinite(s) & (s > 0)
    e = (d - g)[m]
    k = np.abs(e) <= 2
    if not k.any():
        return None
    r = e[k] / s[m][k]
    return dict(rms_error_over_sigma=float(np.sqrt(np.mean(r ** 2))),
                within_2_sigma_percent=float(100.0 * np.mean(np.abs(r) < 2)),
                median_sigma=float(np.median(s[m][k])), pixels=int(k.sum()))


def quality(disp, gt, nonocc, border=4):
    b = border
    d, g, n = disp[b:-b, b:-b], gt[b:-b, b:-b], nonocc[b:-b, b:-b]
    valid = np.isfinite(d)
    err = np.where(valid, np.abs(d - g), np.inf)
    q = dict(invalid=100.0 * (1 - valid.mean()))
    for k in (1, 2):
        q[f"bad{k}_nonocc"] = 100.0 * (err[n] > k).mean()
        q[f"bad{k}_all"] = 100.0 * (err > k).mean()
    sub = n & (err <= 2)
    q["rmse_subpixel"] = float(np.sqrt(np.mean((d - g)[sub] ** 2))) if sub.any() else None
    return {k: (float(v) if v is not None else None) for k, v in q.items()}


# ---------------------------------------------------------------- report
JOB = os.path.join(os.path.dirname(os.path.abspath(__file__)), "opencv_pair_job.py")


def whole_jobs(rig, paths, work, rig_args, fast_args, n, gt, nonocc):
    """Whole processes, interleaved, n rounds: the rig's default and fast modes against
    OpenCV's StereoSGBM (3-way, block 3) and StereoBM as Python jobs (opencv_pair_job.py:
    interpreter, imports, reading the PNGs, matching, writing a float TIFF). Each round runs
    the four once, in turn, so that a drift of the machine's speed moves them alike; each
    round's peer seconds / rig seconds is a paired ratio. Returns the medians, the ratios'
    medians and quartiles, and each job's quality on its last output."""
    jobs = {
        "rig default": rig_cmd(rig, paths, os.path.join(work, "job_rig"), rig_args),
        "rig fast": rig_cmd(rig, paths, os.path.join(work, "job_rig_fast"), fast_args),
        "OpenCV SGBM 3-way block 3 (job)": [sys.executable, JOB, "sgbm3way", paths["left"], paths["right"],
                                            os.path.join(work, "job_sgbm.tif"), str(NDISP), str(THREADS)],
        "OpenCV StereoBM (job)": [sys.executable, JOB, "bm", paths["left"], paths["right"],
                                  os.path.join(work, "job_bm.tif"), str(NDISP), str(THREADS)],
    }
    outs = {"rig default": os.path.join(work, "job_rig", "disparity.tif"),
            "rig fast": os.path.join(work, "job_rig_fast", "disparity.tif"),
            "OpenCV SGBM 3-way block 3 (job)": os.path.join(work, "job_sgbm.tif"),
            "OpenCV StereoBM (job)": os.path.join(work, "job_bm.tif")}
    times = {k: [] for k in jobs}
    for name, cmd in jobs.items():  # one untimed run each: the page cache and the venv warm
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            return dict(error=f"{name} failed: {p.stderr.strip()[-300:]}")
    for _ in range(n):
        for name, cmd in jobs.items():
            t0 = time.perf_counter()
            subprocess.run(cmd, capture_output=True, text=True, check=True)
            times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}

    def ratio(peer, mine):
        r = [a / b for a, b in zip(times[peer], times[mine])]
        q = statistics.quantiles(r, n=4) if len(r) >= 2 else [r[0]] * 3
        return dict(median=statistics.median(r), q1=q[0], q3=q[2])
    quality_of = {}
    for k, f in outs.items():
        try:
            quality_of[k] = quality(tifffile.imread(f).astype(np.float32), gt, nonocc)
        except (OSError, ValueError):
            quality_of[k] = None
    return dict(rounds=n, median_seconds=med, quality=quality_of,
                sgbm_over_rig_default=ratio("OpenCV SGBM 3-way block 3 (job)", "rig default"),
                bm_over_rig_fast=ratio("OpenCV StereoBM (job)", "rig fast"))


def table(rows, rig_row):
    cols = ("method", "seconds", "Mcand/s", "rig/peer", "bad1 no", "bad2 no", "bad1 all",
            "bad2 all", "invalid%", "RMSE<=2")
    fmt = "{:<34} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}"
    f = lambda v, p=2: "-" if v is None else f"{v:.{p}f}"
    lines = [fmt.format(*cols)]
    for r in rows:
        q = r.get("quality") or {}
        if r.get("failed"):
            lines.append(f"{r['method']:<34} FAILED: {r['failed']}")
            continue
        lines.append(fmt.format(r["method"][:34], f(r["seconds"], 3), f(r["throughput"] / 1e6, 1),
                                f(r.get("rig_over_peer")), f(q.get("bad1_nonocc")),
                                f(q.get("bad2_nonocc")), f(q.get("bad1_all")), f(q.get("bad2_all")),
                                f(q.get("invalid")), f(q.get("rmse_subpixel"), 3)))
    if rig_row.get("wall_seconds") is not None:
        lines.append(f"rig: whole command {rig_row['wall_seconds']:.3f} s (median wall), "
                     f"candidates reported {rig_row.get('candidates')}")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rig", required=True, help="the rig binary (e.g. target/release/rig)")
    ap.add_argument("--work", required=True, help="folder for the pair, the truth and the outputs")
    ap.add_argument("--json", action="store_true", help="print JSON instead of the table")
    ap.add_argument("--size", default="900x600", help="WxH of the pair (default 900x600)")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per method; the median counts")
    ap.add_argument("--rig-args", default="", help='extra rig flags, e.g. "--aggregate sgm"')
    ap.add_argument("--bm-block", type=int, default=9, help="StereoBM block size (odd, default 9)")
    ap.add_argument("--paired", type=int, default=15,
                    help="interleaved rig/StereoBM pairs for the paired throughput ratio (0: none)")
    ap.add_argument("--no-hh", action="store_true", help="skip SGBM's 8-path MODE_HH (slowest)")
    ap.add_argument("--noise", type=float, default=1.5, help="Gaussian noise sigma in grey levels")
    ap.add_argument("--supersample", type=int, default=4, help="samples per pixel side (default 4)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=9,
                    help="interleaved rounds of whole processes (rig default and fast, OpenCV "
                         "SGBM 3-way and StereoBM jobs); 0: none")
    ap.add_argument("--fast-args", default="--filter none",
                    help='the rig\'s fast mode (default "--filter none")')
    a = ap.parse_args()
    W, H = (int(v) for v in a.size.lower().split("x"))
    os.makedirs(a.work, exist_ok=True)
    cv2.setNumThreads(THREADS)
    load = os.getloadavg()[0]
    if load > 1.0:
        log(f"warning: load average {load:.2f} before the run: timings will be disturbed")

    imgs, paths, gt, nonocc, sanity = render_pair(W, H, a.supersample, a.noise, a.seed, a.work)
    pixel_cands = W * H * NDISP
    rows = []

    disp, info = run_rig(a.rig, paths, a.work, a.rig_args, a.repeat, gt.shape)
    rig_row = dict(method="rig match pair" + (f" {a.rig_args}" if a.rig_args else ""), **info)
    if disp is None:
        rig_row["failed"] = info["error"]
        log("rig: no result:", info["error"])
    else:
        s = info["rig_seconds"]
        if s is None:
            log("rig: no `seconds` in its JSON; its wall-clock time stands in")
            s = info["wall_seconds"]
        rig_row.update(seconds=s, throughput=pixel_cands / s, quality=quality(disp, gt, nonocc))
        sig = rig_row.pop("sigma", None)
        if sig is not None:
            rig_row["sigma_check"] = sigma_check(disp, sig, gt, nonocc)
    rig_row.pop("sigma", None)
    rows.append(rig_row)

    for name, m in opencv_peers(a.bm_block, not a.no_hh):
        log(f"{name}: {a.repeat} timed runs")
        disp, s = run_peer(m, imgs["left"], imgs["right"], a.repeat)
        tag = name.split("(")[0].strip().lower().replace(" ", "_")
        tifffile.imwrite(os.path.join(a.work, f"{tag}.tif"), disp)
        row = dict(method=name, seconds=s, throughput=pixel_cands / s, quality=quality(disp, gt, nonocc))
        if "throughput" in rig_row:
            row["rig_over_peer"] = rig_row["throughput"] / row["throughput"]
        rows.append(row)

    bm = rows[1]
    sgbm = rows[2]
    paired = None
    if a.paired > 0 and "throughput" in rig_row:
        log(f"paired: {a.paired} interleaved rig/StereoBM runs")
        bm_matcher = opencv_peers(a.bm_block, False)[0][1]
        paired = paired_ratio(rig_cmd(a.rig, paths, os.path.join(a.work, "rig_out"), a.rig_args),
                              bm_matcher, imgs["left"], imgs["right"], a.paired)
    ratios = dict(rig_throughput_over_bm=None, rig_bad2_over_sgbm_nonocc=None, rig_bad2_over_sgbm_all=None)
    if "quality" in rig_row:
        ratios["rig_throughput_over_bm"] = rig_row["throughput"] / bm["throughput"]
        for k in ("nonocc", "all"):
            ref = sgbm["quality"][f"bad2_{k}"]
            ratios[f"rig_bad2_over_sgbm_{k}"] = rig_row["quality"][f"bad2_{k}"] / ref if ref else None
    setup = dict(size=[W, H], disparities=[0, NDISP - 1], opencv=cv2.__version__,
                 opencv_threads=cv2.getNumThreads(), cpu_count=os.cpu_count(), repeat=a.repeat,
                 load_average_at_start=load, noise_sigma=a.noise, supersample=a.supersample, seed=a.seed, border=4,
                 throughput_unit="width*height*64 pixel-candidates per second")
    ratios["rig_throughput_over_bm_paired"] = paired
    jobs = None
    if a.jobs > 0:
        log(f"whole processes: {a.jobs} interleaved rounds")
        jobs = whole_jobs(a.rig, paths, a.work, a.rig_args, a.fast_args, a.jobs, gt, nonocc)
    if a.json:
        print(json.dumps(dict(setup=setup, sanity=sanity, methods=rows, ratios=ratios, jobs=jobs),
                         indent=2))
        return
    print(f"{W}x{H}, disparities 0..{NDISP - 1}, OpenCV {cv2.__version__} on {cv2.getNumThreads()} "
          f"threads ({os.cpu_count()} CPUs), median of {a.repeat} runs; bad-k in % (no = "
          f"non-occluded), invalid counted as bad, 4 px border ignored; sanity MAD {sanity['mad']:.2f} "
          f"(noise alone {sanity['mad_noise_only']:.2f})")
    print(table(rows, rig_row))
    f = lambda v: "-" if v is None else f"{v:.3f}"
    print(f"rig throughput / StereoBM: {f(ratios['rig_throughput_over_bm'])}; rig bad-2 / SGBM bad-2: "
          f"{f(ratios['rig_bad2_over_sgbm_nonocc'])} non-occluded, {f(ratios['rig_bad2_over_sgbm_all'])} all")
    if paired:
        print(f"rig throughput / StereoBM, {paired['pairs']} interleaved pairs: median "
              f"{paired['median']:.3f} (quartiles {paired['q1']:.3f}-{paired['q3']:.3f})")
    if jobs and "error" not in jobs:
        print(f"whole processes, median of {jobs['rounds']} interleaved rounds (seconds; bad-2 "
              f"non-occluded / all):")
        for k, v in jobs["median_seconds"].items():
            q = jobs["quality"].get(k) or {}
            print(f"  {k:<34} {v:6.3f} s   bad-2 {f(q.get('bad2_nonocc'))} / {f(q.get('bad2_all'))}")
        for k, lab in (("sgbm_over_rig_default", "SGBM 3-way job / rig default"),
                       ("bm_over_rig_fast", "StereoBM job / rig fast")):
            r = jobs[k]
            print(f"  {lab}: {r['median']:.2f} (quartiles {r['q1']:.2f}-{r['q3']:.2f}; "
                  f"above 1: the rig is faster)")
    elif jobs:
        print(f"whole processes: {jobs['error']}")
    sc = rig_row.get("sigma_check")
    if sc:
        print(f"rig sigma.tif on {sc['pixels']} pixels within 2 px: RMS(true error / sigma) "
              f"{sc['rms_error_over_sigma']:.2f} (1 when honest), {sc['within_2_sigma_percent']:.1f} % "
              f"within 2 sigma (95 % for a Gaussian), median sigma {sc['median_sigma']:.3f} px")


if __name__ == "__main__":
    main()
