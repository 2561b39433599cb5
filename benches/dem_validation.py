#!/usr/bin/python3
"""`rig dtm` on the validation scenes (tests/data/validation/scenes, made by a renderer that is
not ours), measured as tests/validation.rs measures them but over every post: the DEM's RMSE
in pixels of parallax (flying height / base x GSD), its coverage of the true posts two photos
see (by the scene's own collinearity and pixels), RMS(true error / sigma) and the share within
2 sigma.

usage: /usr/bin/python3 benches/dem_validation.py [--rig PATH] [--work DIR] METHOD [SCENE...]
  METHOD: sweep, mgcm or oslsm; SCENE: lidar-banks, jacksboro-wide, jacksboro-close (all).
Needs numpy and GDAL's Python bindings (python3-gdal)."""
import sys, json, os, shutil, subprocess, re, time, argparse
import numpy as np
from osgeo import gdal
ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument('--rig', default='target/release/rig')
ap.add_argument('--work', default='/tmp/dem-validation', help='scenes are copied here and run')
ap.add_argument('method', choices=['sweep', 'mgcm', 'oslsm'])
ap.add_argument('scenes', nargs='*', default=['lidar-banks', 'jacksboro-wide', 'jacksboro-close'])
args = ap.parse_args()
SRC = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tests', 'data', 'validation', 'scenes')
RIG = args.rig; method = args.method; scenes = args.scenes
def arr(p,b=1):
    ds=gdal.Open(p); band=ds.GetRasterBand(b); a=band.ReadAsArray().astype(float); nd=band.GetNoDataValue()
    if nd is not None: a[a==nd]=np.nan
    return a, ds.GetGeoTransform()
def seen_by(scene, d, X, Y, Z):
    """How many photos see each ground point (X, Y, Z): by the scene's own collinearity
    (scene.json's conventions), inside the frame and on a pixel that is not 0 (a ray that
    missed the DEM)."""
    E0=scene['object_system'].get('E0',0); N0=scene['object_system'].get('N0',0)
    seen=np.zeros(X.shape,int)
    for ph in scene['photos']:
        e=ph['exterior']; i=ph['interior']; M=np.array(e['M_object_to_image'])
        dX=X-E0-e['X0']; dY=Y-N0-e['Y0']; dZ=Z-e['Z0']
        u=M[0,0]*dX+M[0,1]*dY+M[0,2]*dZ; v=M[1,0]*dX+M[1,1]*dY+M[1,2]*dZ; w=M[2,0]*dX+M[2,1]*dY+M[2,2]*dZ
        c=i['focal_mm']; xp,yp=i['principal_point_mm']
        x=xp-c*u/w; y=yp-c*v/w; p=i['pixel_size_um']/1000; W,H=i['image_size_px']
        col=x/p+(W-1)/2; row=(H-1)/2-y/p
        img=gdal.Open(f"{d}/{ph['file']}").ReadAsArray()
        ok=np.isfinite(col)&np.isfinite(row)&(col>=0)&(row>=0)&(col<=W-1)&(row<=H-1)
        ci=np.clip(np.nan_to_num(np.round(col)).astype(int),0,W-1); ri=np.clip(np.nan_to_num(np.round(row)).astype(int),0,H-1)
        ok&=img[ri,ci]!=0
        seen+=ok
    return seen

for sc in scenes:
    d=os.path.join(args.work, sc)
    if not os.path.exists(d): shutil.copytree(f'{SRC}/{sc}',d)
    s=json.load(open(f'{d}/scene.json'))
    t=open(f'{d}/project.toml').read()
    t=re.sub(r'method = "\w+"',f'method = "{method}"',t)
    open(f'{d}/p_{method}.toml','w').write(t)
    out=f'{d}/out_{method}'; shutil.rmtree(out,ignore_errors=True)
    t0=time.time()
    r=subprocess.run([RIG,'dtm',f'{d}/p_{method}.toml','--out',out,'--json'],capture_output=True,text=True)
    took=time.time()-t0
    if r.returncode!=0: print(sc,method,'FAILED',r.stderr[-600:]); continue
    truth,tg=arr(f'{d}/truth_dem.tif')
    dem,g=arr(f'{out}/dem.tif'); sig,_=arr(f'{out}/quality.tif',1)
    rows,cols=dem.shape
    cc,rr=np.meshgrid(np.arange(cols),np.arange(rows))
    X=g[0]+(cc+0.5)*g[1]; Y=g[3]+(rr+0.5)*g[5]
    # the true surface (bilinear between posts at pixel centres) at our nodes
    fc=(X-tg[0])/tg[1]-0.5; fr=(Y-tg[3])/tg[5]-0.5
    c0=np.floor(fc).astype(int); r0=np.floor(fr).astype(int); a=fc-c0; b=fr-r0
    def at(A,c,r):
        h,w=A.shape; m=(c>=0)&(r>=0)&(c<w)&(r<h); o=np.full(c.shape,np.nan); o[m]=A[r[m],c[m]]; return o
    Z=(at(truth,c0,r0)*(1-a)*(1-b)+at(truth,c0+1,r0)*a*(1-b)+at(truth,c0,r0+1)*(1-a)*b+at(truth,c0+1,r0+1)*a*b)
    seen=seen_by(s,d,X,Y,Z)
    area=(seen>=2)&np.isfinite(Z)
    truth=Z; z=dem; sg=sig
    T,_=arr(f'{d}/truth_dem.tif'); tr,tc=T.shape
    tcc,trr=np.meshgrid(np.arange(tc),np.arange(tr))
    TX=tg[0]+(tcc+0.5)*tg[1]; TY=tg[3]+(trr+0.5)*tg[5]
    tseen=seen_by(s,d,TX,TY,T)
    tarea=tseen>=2
    nc=np.floor((TX-g[0])/g[1]).astype(int); nr=np.floor((TY-g[3])/g[5]).astype(int)
    has=np.isfinite(at(dem,nc,nr))
    tcov=(tarea&has).sum()/tarea.sum()
    px=s['flying_height_m']/s['base_m']*s['gsd_m']
    m=area&np.isfinite(z)
    err=(z-truth)[m]
    cov=m.sum()/area.sum()
    rmse=np.sqrt(np.mean(err**2))/px
    ms=m&np.isfinite(sg)&(sg>0)
    ratio=((z-truth)[ms]/sg[ms])
    rr_=np.sqrt(np.mean(ratio**2)) if ms.any() else float('nan')
    w2=np.mean(np.abs(ratio)<=2) if ms.any() else float('nan')
    print(f'{sc:16s} {method:6s} RMSE {rmse:.3f} px ({np.sqrt(np.mean(err**2)):.2f} m, 1 px={px:.2f} m) coverage {100*tcov:.1f} % of the 2-photo area ({tarea.sum()} posts; {100*cov:.1f} % inside the DEM extent); RMS(err/σ) {rr_:.2f}, {100*w2:.0f} % within 2σ; {took:.0f} s',flush=True)
