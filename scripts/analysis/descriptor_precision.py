#!/usr/bin/env python3
"""descriptor_precision.py MODEL DATA [SCENES] [PAIRS.json]: how often the learned descriptor matches that
registration keeps are right. For each scene's 8-view context set, the model's `descriptors`
output (ONNX Runtime) is matched between every pair of views as `raster/src/register/dense.rs`
matches it before refinement (a 4-pixel grid, mutual nearest neighbours by cosine, at least
0.5, and a ratio of 0.75 on 1 − cos against the best outside the match's 3×3 cells); a match
is right when the true depth and cameras carry its point within 4 pixels of where it landed.
Prints the running count of right matches, all matches and their share, scene by scene.
PAIRS.json (from `unlinked_views.py`) limits it to those pairs of views. MODEL `patches:R`
matches raw pixels instead, the comparison: each pixel's (2R+1)² RGB patch,
less its mean (zero padding at the border).
A measurement for the model card, not part of the product or of CI (numpy, pillow, onnxruntime)."""
import json, sys, numpy as np, onnxruntime as ort
from PIL import Image
model, data = sys.argv[1], sys.argv[2]; nsc = int(sys.argv[3]) if len(sys.argv) > 3 else 40
only = None
if len(sys.argv) > 4:
    only = {}
    for scene, a, b, _ in json.load(open(sys.argv[4])): only.setdefault(scene, set()).add((min(a, b), max(a, b)))
sess = None if model.startswith('patches:') else ort.InferenceSession(model, providers=['CPUExecutionProvider'])
def patches(imgs, r):
    """N,3,H,W → N,3(2r+1)²,H,W: every pixel's RGB patch less its mean."""
    n, c, h, w = imgs.shape; pad = np.pad(imgs, ((0, 0), (0, 0), (r, r), (r, r)))
    out = np.stack([pad[:, :, dy:dy + h, dx:dx + w] for dy in range(2 * r + 1) for dx in range(2 * r + 1)], 2).reshape(n, -1, h, w)
    return out - out.mean(1, keepdims=True)
S = 128; st = 4; RATIO = 0.75; MINCOS = 0.5
def cam(t, f):
    return np.array(f['transform_matrix']), f.get('fl_x', t['fl_x']), f.get('fl_y', t['fl_y']), f.get('cx', t['cx']), f.get('cy', t['cy'])
tot = {}; 
for si in range(nsc):
    scene = f'scene_{si:06d}'
    if only is not None and scene not in only: continue
    t = json.load(open(f'{data}/{scene}/transforms.json'))
    fr = [t['frames'][i] for i in t['eval']['context']['8']]
    imgs = np.stack([np.asarray(Image.open(f'{data}/{scene}/{f["file_path"]}').convert('RGB').resize((S, S)), np.float32) / 255 for f in fr]).transpose(0, 3, 1, 2)
    d = patches(imgs, int(model.split(':')[1])) if sess is None else sess.run(['descriptors'], {'images': imgs})[0]  # N,D,H,W
    d = d / np.linalg.norm(d, axis=1, keepdims=True).clip(1e-12)
    ys, xs = np.mgrid[st // 2:S:st, st // 2:S:st]; ys = ys.ravel(); xs = xs.ravel(); G = S // st
    D = [d[v][:, ys, xs].T for v in range(8)]  # 1024 x Dim
    deps = [np.array(Image.open(f'{data}/{scene}/{f["depth_file_path"]}')).astype(np.float64) * t['depth_unit_m'] for f in fr]
    W = fr[0].get('w', t['w']); sc = S / W
    for a in range(8):
        for b in range(a + 1, 8):
            if only is not None and (a, b) not in only[scene]: continue
            C = D[a] @ D[b].T
            ba = C.argmax(1); bb = C.argmax(0)
            ok = []
            for i in range(len(ba)):
                j = ba[i]
                if bb[j] != i or C[i, j] < MINCOS: continue
                # runner-up outside 3x3 of j
                row = C[i].copy(); jr, jc = divmod(j, G)
                for dr in (-1, 0, 1):
                    for dc in (-1, 0, 1):
                        r, c = jr + dr, jc + dc
                        if 0 <= r < G and 0 <= c < G: row[r * G + c] = -2
                if (1 - C[i, j]) >= RATIO * (1 - row.max()): continue
                ok.append((i, j))
            # GT: project a's pixel into b
            Ta, fx, fy, cx, cy = cam(t, fr[a]); Tb, gx, gy, dx, dy = cam(t, fr[b])
            good = 0
            for i, j in ok:
                u, v = xs[i] + .5, ys[i] + .5
                z = deps[a][int(v / sc), int(u / sc)]
                if z <= 0: continue
                U, V = u / sc, v / sc
                P = np.array([(U - cx) / fx * z, -(V - cy) / fy * z, -z, 1])
                Q = np.linalg.inv(Tb) @ (Ta @ P)
                if -Q[2] <= 0: continue
                ub = (Q[0] / -Q[2] * gx + dx) * sc; vb = (-Q[1] / -Q[2] * gy + dy) * sc
                if abs(ub - (xs[j] + .5)) <= 4 and abs(vb - (ys[j] + .5)) <= 4: good += 1
            k = (a, b); tot.setdefault('all', [0, 0]); tot['all'][0] += good; tot['all'][1] += len(ok)
    print(scene, tot['all'], f"{tot['all'][0] / max(tot['all'][1], 1):.3f}", flush=True)
