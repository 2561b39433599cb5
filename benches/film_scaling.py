#!/usr/bin/env python3
"""Film at its real size: `rig dtm` on one stereo pair made 1x, 16x and 256x larger in pixels
(each photo upsampled 1, 4 and 16 times a side, as a scan of the same film at a finer step),
reporting for each size the wall time, the peak resident memory (the kernel's count for the
child, getrusage), the time per megapixel against the small pair's, and the model's accuracy
against the scene's true DEM, measured here (numpy alone): RMSE and NMAD over the posts both
have, coverage of the true posts inside the model's extent, RMS(error / sigma).

usage: python benches/film_scaling.py --rig target/release/rig --scene DIR [--factors 1,4,16]
       [--photos 1,2] [--work /tmp/film-scaling] [--json]

SCENE is a format-2 project directory with `project.toml`, its photos (grey TIFFs), its
points CSV (pixel columns `col`, `row`) and `truth_dem.tif`: the validation scene
`../shared/validation/scenes/lidar-banks` (600 px photos, 1 m posts), or one `rig sim scene`
writes. Each larger copy has the camera's `pixel_mm` divided by the factor and the points'
pixels moved to the finer grid (centre c -> (c + 0.5) k - 0.5); its photos are 16-bit TIFFs in
512 x 512 Deflate tiles, written tile by tile (a 12 800^2 photo is never held here either).
Needs numpy, tifffile (and imagecodecs for Deflate) in the Python that runs it.
"""
import argparse, json, os, re, resource, shutil, subprocess, sys, time
import numpy as np
import tifffile

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument('--rig', default='target/release/rig')
ap.add_argument('--scene', required=True)
ap.add_argument('--project', default='project.toml', help="the scene's format-2 project file (rig sim scene: block.toml)")
ap.add_argument('--factors', default='1,4,16')
ap.add_argument('--photos', default='1,2', help='ids of the two photos of the pair')
ap.add_argument('--work', default='/tmp/film-scaling')
ap.add_argument('--rig-args', default='', help='extra flags for rig dtm')
ap.add_argument('--json', action='store_true')
args = ap.parse_args()
RIG = os.path.abspath(args.rig)
factors = [int(k) for k in args.factors.split(',')]
keep = args.photos.split(',')


def upsample(src, dst, k, tile=512):
    """Bilinear, pixel centres at c + 0.5 on both grids: the fine pixel i samples the source
    at (i + 0.5)/k - 0.5, edges clamped. Written tile by tile."""
    a = tifffile.imread(src).astype(np.float64)
    h, w = a.shape
    H, W = h * k, w * k

    def axis(n_out, n_in, lo, hi):
        u = (np.arange(lo, hi) + 0.5) / k - 0.5
        u = np.clip(u, 0, n_in - 1)
        i0 = np.minimum(np.floor(u).astype(int), n_in - 2)
        return i0, u - i0

    def tiles():
        for r0 in range(0, H, tile):
            ri, rf = axis(H, h, r0, min(r0 + tile, H))
            for c0 in range(0, W, tile):
                ci, cf = axis(W, w, c0, min(c0 + tile, W))
                top = a[ri][:, ci] * (1 - cf) + a[ri][:, ci + 1] * cf
                bot = a[ri + 1][:, ci] * (1 - cf) + a[ri + 1][:, ci + 1] * cf
                v = top * (1 - rf)[:, None] + bot * rf[:, None]
                out = np.zeros((tile, tile), np.uint16)
                out[:v.shape[0], :v.shape[1]] = np.clip(np.round(v), 0, 65535)
                yield out

    if k == 1:
        tifffile.imwrite(dst, np.clip(np.round(a), 0, 65535).astype(np.uint16),
                         tile=(tile, tile), compression='zlib')
    else:
        tifffile.imwrite(dst, tiles(), shape=(H, W), dtype=np.uint16, tile=(tile, tile),
                         compression='zlib')


def make(k):
    d = os.path.join(args.work, f'x{k}')
    done = os.path.join(d, '.made')
    if os.path.exists(done):
        return d
    shutil.rmtree(d, ignore_errors=True)
    os.makedirs(d)
    text = open(os.path.join(args.scene, args.project)).read()
    # Only the pair's photos.
    blocks = re.split(r'(?m)^(?=\[\[photo\]\])', text)
    head, photos = blocks[0], blocks[1:]
    tail = ''
    kept = []
    for b in photos:
        m = re.match(r'(?s)(\[\[photo\]\].*?)(?=^\[(?!\[)|\Z)', b, re.M)
        body, rest = m.group(1), b[len(m.group(1)):]
        tail += rest
        pid = re.search(r'id\s*=\s*"([^"]+)"', body).group(1)
        if pid in keep:
            kept.append(body)
            img = re.search(r'image\s*=\s*"([^"]+)"', body)
            if img:
                upsample(os.path.join(args.scene, img.group(1)), os.path.join(d, img.group(1)), k)
            else:
                # One of the rig's scans: its sidecar's grid k times finer, the same corner.
                side = re.search(r'scan\s*=\s*"([^"]+)"', body).group(1)
                j = json.load(open(os.path.join(args.scene, side)))
                upsample(os.path.join(args.scene, j['image']), os.path.join(d, j['image']), k)
                g = j['grid']
                g['step_mm'] /= k
                g['width'] *= k
                g['height'] *= k
                json.dump(j, open(os.path.join(d, side), 'w'), indent=1)
    head = re.sub(r'pixel_mm\s*=\s*([0-9.eE+-]+)',
                  lambda m: f'pixel_mm = {float(m.group(1)) / k!r}', head)
    open(os.path.join(d, 'project.toml'), 'w').write(head + ''.join(kept) + tail)
    pts = os.path.join(args.scene, 'points.csv')
    if os.path.exists(pts):
        lines = open(pts).read().splitlines()
        hdr = lines[0].split(',')
        ci, ri, pi = hdr.index('col'), hdr.index('row'), hdr.index('photo')
        out = [lines[0]]
        for ln in lines[1:]:
            f = ln.split(',')
            if f[pi] not in keep:
                continue
            f[ci] = repr((float(f[ci]) + 0.5) * k - 0.5)
            f[ri] = repr((float(f[ri]) + 0.5) * k - 0.5)
            out.append(','.join(f))
        open(os.path.join(d, 'points.csv'), 'w').write('\n'.join(out) + '\n')
    ref = re.search(r'reference\s*=\s*"([^"]+)"', text).group(1)
    shutil.copy(os.path.join(args.scene, ref), os.path.join(d, 'truth_dem.tif'))
    t = open(os.path.join(d, 'project.toml')).read().replace(f'"{ref}"', '"truth_dem.tif"')
    open(os.path.join(d, 'project.toml'), 'w').write(t)
    open(done, 'w').close()
    return d


def geo(path):
    """A GeoTIFF's band 1 (nodata as NaN) and its (x0, dx, y0, dy) from its tags."""
    with tifffile.TiffFile(path) as t:
        p = t.pages[0]
        a = p.asarray().astype(np.float64)
        if a.ndim == 3:
            a = a[0] if a.shape[0] < a.shape[-1] else a[..., 0]
        sc = p.tags['ModelPixelScaleTag'].value
        tp = p.tags['ModelTiepointTag'].value
        nd = p.tags.get('GDAL_NODATA')
        if nd is not None:
            v = float(str(nd.value).strip('\x00'))
            a[a == v] = np.nan
        # GDAL's default: PixelIsArea, the tie point at the corner of pixel (0, 0).
        return a, (tp[3] - tp[0] * sc[0], sc[0], tp[4] + tp[1] * sc[1], -sc[1])


def bilinear(a, g, x, y):
    u = (x - g[0]) / g[1] - 0.5
    v = (y - g[2]) / g[3] - 0.5
    h, w = a.shape
    ok = (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1)
    u = np.clip(u, 0, w - 1.001)
    v = np.clip(v, 0, h - 1.001)
    i, j = u.astype(int), v.astype(int)
    fu, fv = u - i, v - j
    z = (a[j, i] * (1 - fu) * (1 - fv) + a[j, i + 1] * fu * (1 - fv)
         + a[j + 1, i] * (1 - fu) * fv + a[j + 1, i + 1] * fu * fv)
    return np.where(ok, z, np.nan)


def judge(out, d):
    dem, g = geo(os.path.join(out, 'dem.tif'))
    sig, _ = geo(os.path.join(out, 'quality.tif'))
    truth, tg = geo(os.path.join(d, 'truth_dem.tif'))
    rows, cols = dem.shape
    X = g[0] + (np.arange(cols) + 0.5) * g[1]
    Y = g[2] + (np.arange(rows) + 0.5) * g[3]
    X, Y = np.meshgrid(X, Y)
    t = bilinear(truth, tg, X, Y)
    have = np.isfinite(t)
    both = have & np.isfinite(dem)
    e = dem[both] - t[both]
    s = sig[both]
    ok = np.isfinite(s) & (s > 0)
    return {
        'posts': int(both.sum()),
        'coverage_percent': 100.0 * both.sum() / max(have.sum(), 1),
        'rmse_m': float(np.sqrt(np.mean(e ** 2))),
        'nmad_m': float(1.4826 * np.median(np.abs(e - np.median(e)))),
        'rms_error_over_sigma': float(np.sqrt(np.mean((e[ok] / s[ok]) ** 2))),
    }


def run(d, k):
    out = os.path.join(d, 'out')
    shutil.rmtree(out, ignore_errors=True)
    cmd = [RIG, 'dtm', os.path.join(d, 'project.toml'), '--out', out] + args.rig_args.split()
    # Each run in its own process under /usr/bin/time: the peak resident memory is this
    # child's alone.
    t0 = time.time()
    env = dict(os.environ, RIG_LOG_EVERY_S='0.5')
    r = subprocess.run(['/usr/bin/time', '-f', '%M'] + cmd, capture_output=True, text=True, env=env)
    secs = time.time() - t0
    if r.returncode != 0:
        return {'factor': k, 'failed': r.stderr[-1500:]}
    peak_kib = int(r.stderr.strip().splitlines()[-1])
    read = json.load(open(os.path.join(out, 'report.json')))['photos_read']
    r0 = read[0]
    w, h = r0['window']['width'], r0['window']['height']
    mpx = sum(r['window']['width'] * r['window']['height'] for r in read) / 1e6
    res = {'factor': k, 'photo_px': [w, h], 'megapixels': mpx, 'seconds': secs,
           'peak_mib': peak_kib / 1024, 'read_factor': r0['factor']}
    res.update(judge(out, d))
    res.update(time_left(r.stderr))
    return res


def time_left(log):
    """How honest the progress lines' time left was: for each step of at least 4 s, each line
    after its first tenth whose step still had a tenth and at least 2 s to go (the last
    seconds, where one thread finishes the last band, are left out), |said - true| / true, the
    true time left being the step's end ('done in') less the line's time. The worst such
    error over the steps, and the step it was in."""
    said = {}
    worst = (0.0, '')
    for ln in log.splitlines():
        m = re.match(r'(.*): (\d+)/(\d+) after ([0-9.]+) s \(.*about ([0-9.]+) s left\)', ln)
        if m:
            said.setdefault(m.group(1), []).append((float(m.group(4)), float(m.group(5)),
                                                     int(m.group(2)) / max(int(m.group(3)), 1)))
            continue
        m = re.match(r'(.*): \d+/\d+ done in ([0-9.]+) s', ln)
        if m and m.group(1) in said:
            end = float(m.group(2))
            if end < 4:
                continue
            for at, left, share in said.pop(m.group(1)):
                true = end - at
                if share >= 0.1 and true >= max(2, 0.1 * end):
                    e = abs(left - true) / true
                    if e > worst[0]:
                        worst = (e, m.group(1))
    return {'time_left_worst_error': worst[0], 'time_left_worst_step': worst[1]}


os.makedirs(args.work, exist_ok=True)
rows = []
for k in factors:
    t0 = time.time()
    d = make(k)
    print(f'x{k}: pair made in {time.time() - t0:.0f} s; running rig dtm', file=sys.stderr)
    rows.append(run(d, k))
    print(json.dumps(rows[-1]), file=sys.stderr)

base = next((r for r in rows if 'failed' not in r), None)
if args.json:
    print(json.dumps(rows, indent=1))
else:
    print(f"{'photos':>14} {'pixels':>7} {'time s':>8} {'peak MiB':>9} {'s/Mpx vs 1x':>11} "
          f"{'read 1/':>7} {'RMSE m':>7} {'NMAD m':>7} {'cover %':>7} {'RMS e/s':>7} {'ETA err':>7}")
    for r in rows:
        if 'failed' in r:
            print(f"x{r['factor']}: FAILED\n{r['failed']}")
            continue
        ratio = (r['seconds'] / r['megapixels']) / (base['seconds'] / base['megapixels'])
        print(f"{r['photo_px'][0]:>6} x {r['photo_px'][1]:<6} {r['factor'] ** 2:>6}x {r['seconds']:>8.1f} "
              f"{r['peak_mib']:>9.0f} {ratio:>11.3f} {r['read_factor']:>7} {r['rmse_m']:>7.2f} {r['nmad_m']:>7.2f} "
              f"{r['coverage_percent']:>7.1f} {r['rms_error_over_sigma']:>7.2f} "
              f"{100 * r['time_left_worst_error']:>6.0f}% {r['time_left_worst_step']}")
