#!/usr/bin/python3
"""Turn OSSIM/OTB `.geom` RPCs (ossimRpcModel, polynomial_format B = RPC00B's term order) into
GDAL's `_RPC.TXT`, written by GDAL itself.

Usage: geom_to_rpc_txt.py IN.geom OUT_RPC.TXT

The keywords map one to one onto GDAL's RPC metadata (line_off -> LINE_OFF, ...,
line_num_coeff_00..19 -> LINE_NUM_COEFF, the 20 numbers as written). GDAL then writes the file:
an empty GeoTIFF of the product's size (sparse, nothing but its header) gets the metadata in
its RPC domain with the creation option RPCTXT=YES, so GDAL puts `<name>_RPC.TXT` beside it; the
file is read back through GDAL (gdal.Open(...).GetMetadata('RPC')) and every number compared
with the .geom's before it is kept.
"""
import os
import shutil
import sys
import tempfile

from osgeo import gdal

gdal.UseExceptions()


def read_geom(path):
    kv = {}
    with open(path, encoding="ascii") as f:
        for line in f:
            if ":" in line:
                k, v = line.split(":", 1)
                kv[k.strip()] = v.strip()
    if kv.get("type") != "ossimRpcModel" or kv.get("polynomial_format") != "B":
        sys.exit(f"{path}: not an ossimRpcModel with polynomial_format B")
    return kv


def main(src, dst):
    kv = read_geom(src)
    md = {}
    for key in ["line_off", "samp_off", "lat_off", "long_off", "height_off",
                "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale"]:
        md[key.upper()] = kv[key]
    md["ERR_BIAS"] = kv.get("bias_error", "0")
    md["ERR_RAND"] = kv.get("rand_error", "0")
    for part in ["line_num", "line_den", "samp_num", "samp_den"]:
        md[part.upper() + "_COEFF"] = " ".join(kv[f"{part}_coeff_{k:02d}"] for k in range(20))
    cols, rows = int(kv["number_samples"]), int(kv["number_lines"])
    with tempfile.TemporaryDirectory() as d:
        img = os.path.join(d, "product.tif")
        ds = gdal.GetDriverByName("GTiff").Create(
            img, cols, rows, 1, gdal.GDT_Byte, ["SPARSE_OK=YES", "RPCTXT=YES"])
        ds.SetMetadata(md, "RPC")
        ds = None
        back = gdal.Open(img).GetMetadata("RPC")
        for k, v in md.items():
            want = [float(x) for x in v.split()]
            got = [float(x) for x in back[k].split()]
            if want != got:
                sys.exit(f"{src}: GDAL reads {k} back as {back[k]}, not {v}")
        shutil.copyfile(os.path.join(d, "product_RPC.TXT"), dst)
    print(f"{dst}: {cols} x {rows} px product, 92 numbers as GDAL reads them back")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
