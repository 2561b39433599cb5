#!/usr/bin/env python3
"""One whole OpenCV stereo job, as a user would run it: start Python, read the rectified pair
(PNG), match, write the disparities as a float32 TIFF (NaN where invalid). Called by
stereo_vs_opencv.py once per timed run, so that the time is the whole process's, as the rig's
is: interpreter and imports, decoding, matching, writing.

    opencv_pair_job.py sgbm3way|bm LEFT RIGHT OUT.tif NDISP THREADS
"""
import sys

import cv2
import numpy as np
import tifffile

method, left, right, out, ndisp, threads = sys.argv[1:7]
ndisp, threads = int(ndisp), int(threads)
cv2.setNumThreads(threads)
l = cv2.imread(left, cv2.IMREAD_GRAYSCALE)
r = cv2.imread(right, cv2.IMREAD_GRAYSCALE)
if l is None or r is None:
    sys.exit(f"cannot read {left} or {right}")
if method == "sgbm3way":
    bs = 3  # the peer: StereoSGBM, 3-way, block 3, OpenCV's sample penalties
    m = cv2.StereoSGBM.create(minDisparity=0, numDisparities=ndisp, blockSize=bs,
                              P1=8 * bs * bs, P2=32 * bs * bs, disp12MaxDiff=1, preFilterCap=63,
                              uniquenessRatio=10, speckleWindowSize=100, speckleRange=32,
                              mode=cv2.StereoSGBM_MODE_SGBM_3WAY)
elif method == "bm":
    m = cv2.StereoBM.create(numDisparities=ndisp, blockSize=9)
    m.setPreFilterType(cv2.StereoBM_PREFILTER_XSOBEL)
    m.setPreFilterCap(31)
    m.setTextureThreshold(10)
    m.setUniquenessRatio(15)
    m.setSpeckleWindowSize(100)
    m.setSpeckleRange(32)
    m.setDisp12MaxDiff(1)
else:
    sys.exit(f"unknown method {method}")
raw = m.compute(l, r)
d = raw.astype(np.float32) / 16.0
d[raw < 0] = np.nan
tifffile.imwrite(out, d)
