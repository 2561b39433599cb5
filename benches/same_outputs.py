#!/usr/bin/env python3
"""Whether a change of the code changed any figure: the tests' kinds of scenes run through
`rig`, every file they leave hashed.

    same_outputs.py --rig target/release/rig --work /tmp/same --save before.txt
    (change the code, build)
    same_outputs.py --rig target/release/rig --work /tmp/same --check before.txt

Each case makes its scene with the rig under test (so the scene's own files are compared too)
and runs one `rig dtm` (format 1 from points and from resected photos; format 2 with the sweep,
MGCM and OSLSM; a three-photo block; a tiled run joined by `rig dtm merge`; pushbroom views by
their rigorous models and by their RPCs), `rig match pair` on a rectified pair cut from the
scene, and with --demo `rig demo --seed 3` (two minutes more). A file's hash is its bytes',
except that JSON documents lose the keys that hold times (any key with "second" or "time" in its
name), rates in report.html ("830 points/s", "3.2 s") are blanked, the work directory's
absolute path is read as WORK, a session's time stamp (20261129T181352Z) as STAMP, and logs (*.jsonl) are left out: those change from run to run. --check prints each file
that differs and exits 1.
"""
import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys

TIMED = ("second", "time", "started", "finished")
STAMP = re.compile(rb"\d{8}T\d{6}Z")


def strip_times(x):
    if isinstance(x, dict):
        return {k: strip_times(v) for k, v in x.items() if not any(t in k.lower() for t in TIMED)}
    if isinstance(x, list):
        return [strip_times(v) for v in x]
    return x


def digest(path, work):
    with open(path, "rb") as f:
        data = f.read()
    # Absolute paths name the work directory, which differs between the two runs.
    data = data.replace(os.path.abspath(work).encode(), b"WORK")
    # A calibration session's folder is named by the time it began.
    data = STAMP.sub(b"STAMP", data)
    if path.endswith(".html"):
        data = re.sub(rb"\d[\d.,]*\s*(\w+/s|s)\b", b"RATE", data)
    if path.endswith(".json"):
        try:
            doc = strip_times(json.loads(data))
            data = json.dumps(doc, sort_keys=True).encode()
        except ValueError:
            pass
    return hashlib.sha256(data).hexdigest()


def hashes(root):
    out = {}
    for d, _, files in os.walk(root):
        for f in files:
            if f.endswith(".jsonl") or f.endswith(".log"):
                continue
            p = os.path.join(d, f)
            out[STAMP.sub(b"STAMP", os.path.relpath(p, root).encode()).decode()] = digest(p, root)
    return out


def run(rig, args, cwd):
    r = subprocess.run([rig] + args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    if r.returncode != 0:
        sys.exit(f"rig {' '.join(args)} (in {cwd}) exited {r.returncode}:\n{r.stderr.decode()}")
    return r.stdout


def with_method(src, dst, method, extra=""):
    text = open(src).read()
    text = text.replace('method = "sweep"', f'method = "{method}"')
    with open(dst, "w") as f:
        f.write(text + extra)


def cases(rig, work, demo):
    rig = os.path.abspath(rig)
    s = os.path.join(work, "frame")
    os.makedirs(s)
    run(rig, ["sim", "scene", "--seed", "1", "--area", "40,-4,48,4", "--noise-dn", "100",
              "--out", "scene"], s)
    sc = os.path.join(s, "scene")
    text = open(os.path.join(sc, "project.toml")).read()
    with open(os.path.join(sc, "rigorous.toml"), "w") as f:
        f.write(text.replace('from = "points"', 'from = "rigorous"'))
    run(rig, ["dtm", "scene/project.toml", "--out", "pmf-points"], s)
    run(rig, ["dtm", "scene/rigorous.toml", "--out", "pmf-rigorous"], s)
    for m in ("sweep", "mgcm", "oslsm"):
        with_method(os.path.join(sc, "block.toml"), os.path.join(sc, f"block-{m}.toml"), m)
        run(rig, ["dtm", f"scene/block-{m}.toml", "--out", f"block-{m}"], s)
    for i in (1, 2):
        run(rig, ["dtm", "scene/block.toml", "--tile", f"{i}/2", "--out", f"tiles/{i}"], s)
    run(rig, ["dtm", "merge", "tiles/1", "tiles/2", "--out", "merged"], s)
    shutil.rmtree(os.path.join(s, "tiles"))

    s3 = os.path.join(work, "three")
    os.makedirs(s3)
    run(rig, ["sim", "scene", "--seed", "2", "--photos", "3", "--area", "40,-66,46,-60",
              "--out", "scene"], s3)
    run(rig, ["dtm", "scene/block.toml", "--out", "sweep"], s3)
    with_method(os.path.join(s3, "scene", "block.toml"), os.path.join(s3, "scene", "mgcm.toml"),
                "mgcm")
    run(rig, ["dtm", "scene/mgcm.toml", "--out", "mgcm"], s3)

    pb = os.path.join(work, "pushbroom")
    os.makedirs(pb)
    run(rig, ["sim", "scene", "--sensor", "pushbroom", "--size", "300", "--out", "scene"], pb)
    run(rig, ["dtm", "scene/block.toml", "--out", "rigorous"], pb)
    run(rig, ["dtm", "scene/block-rpc.toml", "--out", "rpc"], pb)

    # A rectified pair: two crops of one photo a known shift apart.
    mp = os.path.join(work, "pair")
    os.makedirs(mp)
    import numpy as np
    from osgeo import gdal
    img = gdal.Open(os.path.join(sc, "photo-1.tiff")).ReadAsArray().astype("float32")
    left, right = img[20:220, 40:260], img[20:220, 33:253]
    drv = gdal.GetDriverByName("GTiff")
    for name, a in (("left.tif", left), ("right.tif", right)):
        ds = drv.Create(os.path.join(mp, name), a.shape[1], a.shape[0], 1, gdal.GDT_Float32)
        ds.GetRasterBand(1).WriteArray(np.ascontiguousarray(a))
        ds = None
    run(rig, ["match", "pair", "left.tif", "right.tif", "--disparity", "0", "16", "--out", "out"],
        mp)

    if demo:
        d = os.path.join(work, "demo")
        os.makedirs(d)
        run(rig, ["demo", "--seed", "3", "--out", "out"], d)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rig", required=True)
    ap.add_argument("--work", required=True, help="a new directory (removed first if it exists)")
    ap.add_argument("--demo", action="store_true", help="rig demo --seed 3 as well")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", help="write the hashes here")
    g.add_argument("--check", help="compare with the hashes saved here")
    a = ap.parse_args()
    if os.path.exists(a.work):
        shutil.rmtree(a.work)
    os.makedirs(a.work)
    cases(a.rig, a.work, a.demo)
    now = hashes(a.work)
    if a.save:
        with open(a.save, "w") as f:
            for k in sorted(now):
                f.write(f"{now[k]}  {k}\n")
        print(f"{len(now)} files hashed into {a.save}")
        return
    before = {}
    for line in open(a.check):
        h, k = line.rstrip("\n").split("  ", 1)
        before[k] = h
    if not a.demo:
        before = {k: v for k, v in before.items() if not k.startswith("demo/")}
    bad = sorted(k for k in set(before) | set(now) if before.get(k) != now.get(k))
    for k in bad:
        what = "new" if k not in before else "gone" if k not in now else "differs"
        print(f"{what}: {k}")
    print(f"{len(now)} files, {len(bad)} not the same")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
