#!/usr/bin/env python3
"""unlinked_views.py DATA [MODEL] [PAIRS.json]: for every view after the first of each scene's 8-view context
set, how registration placed it (`inssplat reconstruct --json`: registered, or continued from the
views before it when no pair links it), its rotation error relative to view 0, and how much of it
the other context views see in truth (true depth and cameras: the share of its pixels that
project into another view and meet the surface there within 5%). Prints, per placement, the
views' rotation error (and its split about the true up: heading, pitch and roll), their
rotation and centre errors by how much of them view 0 and the views chained to it see, their
largest true overlap with another view, and their largest with
view 0 or a view registration chained to it: whether the views that no match links could be
linked by any matcher at all. PAIRS.json gets, for each unlinked view that overlaps view 0 or
a view chained to it by more than 30%, that pair [scene, view, other view, overlap]: the pairs
a matcher could link. Needs numpy and pillow, and target/release/inssplat."""
import collections
import json
import os
import shutil
import subprocess
import sys

import numpy as np

from scene import camera_of, scenes

data = sys.argv[1]
model = sys.argv[2] if len(sys.argv) > 2 else 'models/inssplat-default.onnx'
pairs_out = sys.argv[3] if len(sys.argv) > 3 else None
nv = 8
WORLD_UP = np.array([0, 1.0, 0])


def overlap(ca, da, cb, db):
    """The share of view a's pixels (camera ca, true depth da) that project into view b and meet
    its true surface db there within 5%."""
    h, w = da.shape
    ok = da > 0
    world = ((ca.rays() * da[..., None])[ok] - ca.translation) @ ca.rotation
    ub, vb, zb = cb.project(world @ cb.rotation.T + cb.translation)
    inside = (zb > 1e-3) & (ub >= 0) & (ub < w) & (vb >= 0) & (vb < h)
    ui = np.clip(ub.astype(int), 0, w - 1); vi = np.clip(vb.astype(int), 0, h - 1)
    vis = inside & (np.abs(db[vi, ui] - zb) < 0.05 * zb)
    return vis.sum() / max(ok.sum(), 1)


def relative(c0, ck):
    """Camera k in camera 0's frame: the rotation camera k → camera 0 and k's centre."""
    return c0.rotation @ ck.rotation.T, c0.rotation @ ck.center() + c0.translation


def rot_err(Rp, Rt):
    c = (np.trace(Rp.T @ Rt) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


rows = []
for sc in scenes(data):
    scene = sc.name; ctx = sc.context(nv)
    tmp = f'/tmp/unlinked_views/{scene}'; shutil.rmtree(tmp, ignore_errors=True); os.makedirs(tmp + '/in')
    for k, i in enumerate(ctx): shutil.copy(sc.path(i), f'{tmp}/in/{k:03d}.png')
    out = subprocess.run(['target/release/inssplat', 'reconstruct', '--json', '--model', model, '--out', tmp + '/out', tmp + '/in'], capture_output=True, text=True, check=True).stdout
    cams = json.loads(out)['cameras']
    true = [sc.camera(i) for i in ctx]; pred = [camera_of(c, where=f'{scene}: cameras[{k}]') for k, c in enumerate(cams)]
    depths = [sc.depth(i, np.float64) for i in ctx]
    O = np.array([[overlap(true[a], depths[a], true[b], depths[b]) if a != b else 1.0 for b in range(nv)] for a in range(nv)])
    # The true up in view 0's frame.
    up = true[0].rotation @ WORLD_UP
    for k in range(1, nv):
        Rt, ct = relative(true[0], true[k])
        Rp, cp = relative(pred[0], pred[k])
        others = [O[k, j] for j in range(nv) if j != k]
        # The error split about the true up (view 0's frame): heading, pitch, roll.
        fp, ft = Rp[:, 2], Rt[:, 2]
        hp, ht = fp - (fp @ up) * up, ft - (ft @ up) * up
        heading = np.degrees(np.arccos(np.clip(hp @ ht / np.linalg.norm(hp) / np.linalg.norm(ht), -1, 1)))
        tilt = lambda a, b: abs(np.degrees(np.arcsin(np.clip(a @ up, -1, 1)) - np.arcsin(np.clip(b @ up, -1, 1))))
        # The centre's error relative to view 0, at the depth's scale against metres.
        rows.append(dict(scene=scene, view=k, placement=cams[k]['placement'], rot=rot_err(Rp, Rt), ov0=O[k, 0], ovmax=max(others),
                         centre_err=np.linalg.norm(ct - cp), distance=np.linalg.norm(ct),
                         heading=heading, pitch=tilt(fp, ft), roll=tilt(Rp[:, 0], Rt[:, 0])))
    # What a matcher could link a view to: view 0 and the views registration chained to it.
    linked = [0] + [k for k in range(1, nv) if cams[k]['placement'] == 'registered']
    for r in rows[-(nv - 1):]:
        r['ovlinked'] = max(O[r['view'], j] for j in linked if j != r['view'])
        r['partner'] = max((j for j in linked if j != r['view']), key=lambda j: O[r['view'], j])
by = collections.defaultdict(list)
for r in rows: by[r['placement']].append(r)
for p, rs in by.items():
    rot = np.array([r['rot'] for r in rs]); om = np.array([r['ovmax'] for r in rs])
    ol = np.array([r['ovlinked'] for r in rs])
    print(f'{p:12s} n={len(rs):3d} rot median {np.median(rot):6.2f} mean {rot.mean():6.2f}  GT max overlap median {np.median(om):.2f}  share with ovmax>0.3: {(om>0.3).mean():.2f} >0.1: {(om>0.1).mean():.2f}')
    print(f'{"":12s} error medians about the true up: heading {np.median([r["heading"] for r in rs]):.1f}, pitch {np.median([r["pitch"] for r in rs]):.1f}, roll {np.median([r["roll"] for r in rs]):.1f}')
    print(f'{"":12s} with view 0 or a view chained to it: overlap median {np.median(ol):.2f}, views over 0.3: {(ol>0.3).sum()}, under 0.05: {(ol<0.05).sum()}')
    for lo, hi in [(0, 0.05), (0.05, 0.3), (0.3, 1.01)]:
        band = [r for r in rs if lo <= r['ovlinked'] < hi]
        if band:
            print(f'{"":12s} seen {lo:.2f}-{hi:.2f} by them: {len(band)} views, rotation error median {np.median([r["rot"] for r in band]):.1f}, '
                  f'centre error median {np.median([r["centre_err"] for r in band]):.2f} at true distance from view 0 {np.median([r["distance"] for r in band]):.2f}')
if pairs_out:
    json.dump([[r['scene'], r['view'], int(r['partner']), float(r['ovlinked'])] for r in rows if r['placement'] != 'registered' and r['ovlinked'] > 0.3], open(pairs_out, 'w'))
