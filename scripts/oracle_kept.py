"""What the oracle radar (train --radar-oracle, prep::radar_oracle) keeps of a prepared folder's
radar returns, and how far the real returns' depths are from the lidar depth the oracle gives
them (every 10th of the first 200 samples).  Usage: python3 scripts/oracle_kept.py PREPARED
Mirrors the rule of crates/prep/src/radar_oracle.rs (3 px, Euclidean, nearest valid pixel)."""
import struct,sys,json,numpy as np
ROOT=sys.argv[1]
from PIL import Image
def rp(path):
    b=open(path,'rb').read(); o=8
    ver,=struct.unpack_from('<I',b,o); o+=4
    fx,fy,cx,cy=struct.unpack_from('<4d',b,o); o+=32
    W,H=struct.unpack_from('<2I',b,o); o+=8
    nc,=struct.unpack_from('<I',b,o); o+=4
    for _ in range(nc):
        l,=struct.unpack_from('<H',b,o); o+=2+l
    ng,=struct.unpack_from('<I',b,o); o+=4
    tot=0
    for _ in range(ng):
        c,s,x,y,z,n=struct.unpack_from('<HH3fI',b,o); o+=20; tot+=n
    pts=np.frombuffer(b,dtype='<f4',count=tot*3,offset=o).reshape(-1,3)
    return (fx,fy,cx,cy,W,H),pts
idx=json.load(open(ROOT+"/index.json"))
samples=idx['samples'] if isinstance(idx,dict) else idx
tk=0;td=0;tin=0;errs=[];rerrs=[]
for e in samples[:200:10]:
    d=ROOT+'/'+e['sample_token']
    (fx,fy,cx,cy,W,H),p=rp(d+'/radar_points.bin')
    t=np.array(Image.open(d+'/lidar_dense.png')).astype(np.float32)/256.0
    z=p[:,2]; ok=z>1
    u=fx*p[:,0]/z+cx; v=fy*p[:,1]/z+cy
    ok&=(u>1)&(u<W-1)&(v>1)&(v<H-1)
    x=np.floor(u*0.5).astype(int); y=np.floor(v*0.5).astype(int)-100
    ok&=(x>=0)&(x<800)&(y>=0)&(y<350)
    for i in np.nonzero(ok)[0]:
        tin+=1
        best=None
        for dy in range(-3,4):
            for dx in range(-3,4):
                if dx*dx+dy*dy>9: continue
                xx,yy=x[i]+dx,y[i]+dy
                if 0<=xx<800 and 0<=yy<350 and t[yy,xx]>0:
                    dd=dx*dx+dy*dy
                    if best is None or dd<best[0]: best=(dd,t[yy,xx])
        if best: tk+=1; rerrs.append(abs(z[i]-best[1])/best[1])
    td+=len(z)
print('returns total',td,'in frame',tin,'kept',tk, 'kept/in-frame %.2f'%(tk/max(tin,1)))
r=np.array(rerrs); print('radar depth rel err vs oracle: median %.3f, within 10%%: %.2f'%(np.median(r),(r<0.1).mean()))
