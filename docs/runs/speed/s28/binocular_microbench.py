# Times the compiled binocular term against its torch form (warp_shifted_to_view + masked_l1), forward + backward, and
# compares value, mask and gradients, on synthetic images at the protocol sizes: PYTHONPATH=TREE python binocular_microbench.py
import torch, time, numpy as np
from dataclasses import replace
from gsgs_engine.cameras import Camera
from gsgs_engine.train.techniques.binocular import warp_shifted_to_view, masked_l1, shifted_camera, surface_depth, MIN_OPAQUE
from gsgs_engine.train.fused_binocular import binocular_l1
torch.manual_seed(0)
def cam(w,h):
    import inspect
    return Camera(R=np.eye(3), t=np.zeros(3), fx=w*1.1, fy=w*1.1, cx=w/2+0.3, cy=h/2-0.2, width=w, height=h)
def run(w,h,scale,b, reps=5):
    c = cam(w,h); s = shifted_camera(c, b)
    if scale != 1: s = s.scaled(scale)
    img0 = torch.rand(s.height, s.width, 3)
    depth0 = (2 + torch.rand(h, w)); alpha0 = torch.rand(h,w)*1.2
    depth0[0,:5] = float('nan'); depth0[1,:3] = 0.0; depth0[2, :2] = 1e-8
    target = torch.rand(h,w,3)
    out = {}
    for name in ('torch','fused'):
        img = img0.clone().requires_grad_(True); depth = (depth0*alpha0).clone().requires_grad_(True); alpha = alpha0.clone().requires_grad_(True)
        z = surface_depth(depth, alpha)
        if name == 'torch':
            warped, valid = warp_shifted_to_view(c, z, s, img)
            mask = (valid & (alpha.detach() > MIN_OPAQUE))
            l = masked_l1(warped, target, mask)
        else:
            l, mask = binocular_l1(c, z, s, img, target, alpha, MIN_OPAQUE)
        l.backward()
        out[name] = (l.item(), mask, img.grad, depth.grad, alpha.grad)
        # timing
        ts = []
        for _ in range(reps):
            img = img0.clone().requires_grad_(True); depth = (depth0*alpha0).clone().requires_grad_(True); alpha = alpha0.clone().requires_grad_(True)
            t0 = time.perf_counter()
            z = surface_depth(depth, alpha)
            if name == 'torch':
                warped, valid = warp_shifted_to_view(c, z, s, img)
                mask = (valid & (alpha.detach() > MIN_OPAQUE)); l = masked_l1(warped, target, mask)
            else:
                l, mask = binocular_l1(c, z, s, img, target, alpha, MIN_OPAQUE)
            l.backward(); ts.append(time.perf_counter()-t0)
        out[name] += (min(ts),)
    a, f = out['torch'], out['fused']
    def rel(x,y): return float((x-y).abs().max()/ (y.abs().max()+1e-30))
    print(f"{w}x{h} scale {scale} b {b}: loss {a[0]:.8f} {f[0]:.8f} mask diff {(a[1]!=f[1]).sum().item()} of {a[1].sum().item()} "
          f"gimg {rel(f[2],a[2]):.2e} gdepth {rel(f[3],a[3]):.2e} galpha {rel(f[4],a[4]):.2e} | torch {1000*a[5]:.2f} ms fused {1000*f[5]:.2f} ms")
for (w,h,sc,b) in [(400,400,1.0,0.3),(400,400,1.0,-0.3),(504,378,0.5,0.25),(504,378,0.5,-2.0),(37,23,1.0,0.5),(33,17,0.5,0.1)]:
    run(w,h,sc,b)
