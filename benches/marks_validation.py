#!/usr/bin/env python3
"""`rig measure` on the independent validation marks (issue 37), against their truth and the
peers' ECC.

The marks (../shared/validation/marks, see its README) are 71 x 71 16-bit TIFFs rendered by a
renderer that is not part of this project, with exact centres in truth.csv. Their convention is
the rig's: the centre of pixel (0, 0) is at (0, 0), so no conversion is made. The rig is given
only start.csv's approximate centre (--near), never the truth.

Per type x condition it prints: the rig's RMSE (radial, px, over all marks it returned a centre
for), RMS(error / sigma) over both axes pooled, the share of marks whose radial error lies within
2 sigma (per axis: |d| < 2 sigma on both), the gate's accepted / refused counts, the marks within
3 sigma on both axes that the gate refused, and ECC's RMSE from peers_summary.csv.

    python3 benches/marks_validation.py --rig target/release/rig [--data DIR] [--flat] [--json]

--flat also gives each mark a flat of its camera (--stripes-from): a 71-column image of the
same row shift and stripes at 180 DN, which the rig's stripe estimate reads off. Only numpy and
the standard library are needed.
"""
import argparse, csv, json, math, os, subprocess, sys, tempfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np

TYPES = ["cross", "corner", "midside"]
CONDS = ["a_read2", "b_read8", "c_ccd", "d_avg32", "d_avg32_16bit"]

# The mark files (the validation README's ideal marks, in px), shared with tests/validation.rs.
MARK_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "data", "validation", "marks")
MARKS = {t: open(os.path.join(MARK_DIR, t + ".toml")).read() for t in TYPES}


def write_tiff16(path, img):
    """A minimal uncompressed 16-bit greyscale TIFF (little endian)."""
    h, w = img.shape
    data = np.asarray(img, dtype="<u2").tobytes()
    entries = [
        (256, 3, 1, w), (257, 3, 1, h), (258, 3, 1, 16), (259, 3, 1, 1), (262, 3, 1, 1),
        (273, 4, 1, 8), (277, 3, 1, 1), (278, 3, 1, h), (279, 4, 1, len(data)),
    ]
    ifd_off = 8 + len(data)
    out = bytearray(b"II*\x00" + ifd_off.to_bytes(4, "little") + data)
    out += len(entries).to_bytes(2, "little")
    for tag, typ, cnt, val in entries:
        out += tag.to_bytes(2, "little") + typ.to_bytes(2, "little") + cnt.to_bytes(4, "little")
        out += (val.to_bytes(2, "little") + b"\x00\x00") if typ == 3 else val.to_bytes(4, "little")
    out += (0).to_bytes(4, "little")
    with open(path, "wb") as f:
        f.write(out)


def flat_for(path, parity, phase, rows=240, cols=71):
    """The camera's flat: 180 DN with the row shift (+4.5 DN on rows of `parity`) and the dark
    stripes (-5 DN on columns with (col - phase) mod 12 < 3), as a 32-frame mean at 16 bits."""
    img = np.full((rows, cols), 180.0)
    img[int(parity)::2, :] += 4.5
    c = np.arange(cols)
    img[:, ((c - int(phase)) % 12) < 3] -= 5.0
    write_tiff16(path, np.round(img * 256))


def run_one(rig, markfile, img, near, extra):
    cmd = [rig, "measure", img, "--mark", markfile, "--near", "%.3f,%.3f" % near,
           "--search", "5", "--json", "-q"] + extra
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        return {"error": p.stderr.strip()}
    return json.loads(p.stdout)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser()
    ap.add_argument("--rig", default=os.path.join(here, "..", "target", "release", "rig"))
    ap.add_argument("--data", default="/work/shared/validation/marks")
    ap.add_argument("--flat", action="store_true")
    ap.add_argument("--types", default=",".join(TYPES))
    ap.add_argument("--conds", default=",".join(CONDS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--per-mark", action="store_true")
    ap.add_argument("--rig-args", default="")
    a = ap.parse_args()

    ecc = {}
    with open(os.path.join(a.data, "peers_summary.csv")) as f:
        for r in csv.DictReader(f):
            if r["method"] == "ecc_affine":
                ecc[(r["type"], r["condition"])] = float(r["rmse_px"])

    tmp = tempfile.mkdtemp(prefix="marksval-")
    rows = []
    for t in a.types.split(","):
        mf = os.path.join(tmp, t + ".toml")
        with open(mf, "w") as f:
            f.write(MARKS[t])
        for c in a.conds.split(","):
            d = os.path.join(a.data, t, c)
            truth = {r["file"]: r for r in csv.DictReader(open(os.path.join(d, "truth.csv")))}
            start = list(csv.DictReader(open(os.path.join(d, "start.csv"))))
            jobs = []
            for s in start:
                extra = a.rig_args.split() if a.rig_args else []
                tr = truth[s["file"]]
                if a.flat and tr["row_shift_parity"] != "":
                    fp = os.path.join(tmp, "%s_%s_%s.flat.tif" % (t, c, s["file"][:-4]))
                    flat_for(fp, tr["row_shift_parity"], tr["stripe_phase"])
                    extra += ["--stripes-from", fp]
                jobs.append((s["file"], os.path.join(d, s["file"]),
                             (float(s["approx_col"]), float(s["approx_row"])), extra))
            with ThreadPoolExecutor(a.jobs) as ex:
                res = list(ex.map(lambda j: run_one(a.rig, mf, j[1], j[2], j[3]), jobs))
            e2, z2, nz, in2, acc, ref, ref3, n = [], [], 0, 0, 0, 0, 0, 0
            reasons = {}
            for (fn, _, _, _), r in zip(jobs, res):
                tr = truth[fn]
                if "error" in r or r.get("col") is None:
                    ref += 1
                    reasons["error"] = reasons.get("error", 0) + 1
                    continue
                dc, dr = r["col"] - float(tr["col"]), r["row"] - float(tr["row"])
                sc, sr = r["sigma_col"], r["sigma_row"]
                n += 1
                e2.append(dc * dc + dr * dr)
                z2 += [(dc / sc) ** 2, (dr / sr) ** 2]
                if abs(dc) < 2 * sc and abs(dr) < 2 * sr:
                    in2 += 1
                within3 = abs(dc) < 3 * sc and abs(dr) < 3 * sr
                if r["accepted"]:
                    acc += 1
                else:
                    ref += 1
                    reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
                    if within3:
                        ref3 += 1
                if a.per_mark:
                    print("%s %s %s d=(%+.4f,%+.4f) s=(%.4f,%.4f) %s %s blur=%s" % (
                        t, c, fn, dc, dr, sc, sr, r["accepted"], r.get("reason"), r.get("blur_px")),
                        file=sys.stderr)
            row = dict(type=t, condition=c, n=n,
                       rmse=math.sqrt(sum(e2) / len(e2)) if e2 else None,
                       z=math.sqrt(sum(z2) / len(z2)) if z2 else None,
                       within2=in2 / n if n else None, accepted=acc, refused=ref,
                       refused_within3=ref3, reasons=reasons, ecc=ecc.get((t, c)))
            rows.append(row)
            if not a.json:
                print("%-8s %-14s RMSE %.4f px  RMS(e/s) %.2f  2s %3.0f%%  gate %2d/%2d acc"
                      " (%d within 3s refused) %s  ECC %.4f" % (
                          t, c, row["rmse"], row["z"], 100 * row["within2"], acc, acc + ref,
                          ref3, reasons if reasons else "", row["ecc"]), flush=True)
    if a.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
