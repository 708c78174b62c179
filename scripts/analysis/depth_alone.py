#!/usr/bin/env python3
"""Does the network's depth use the other views? Each 8-view context set of a dataset's scenes
is run through an exported model twice with ONNX Runtime: all 8 views together, and each view
alone. Prints the depth AbsRel of both (each view at its own median scale, and each scene at
its own), the paired difference, the within-view slope of log predicted on log true depth,
and how much the two predictions differ.

With `--rays` (a file with the optional `rays` input), the views together read their true
cameras as rays (the pipeline's second pass, with the cameras registration would ideally
give; `proto/src/rays.rs`, centres over the views' median true depth), and each view alone
reads its own camera's rays; without it both read none (the pipeline's first pass).
`--first=N` takes each scene's first N frames, consecutive along its trajectory and so
overlapping, instead of its N-view context set.

A measurement for the model card, not part of the product or of CI:
    pip install onnxruntime numpy pillow
    python3 scripts/analysis/depth_alone.py models/inssplat-default.onnx data/val40 [8] [--rays] [--first=4]
"""
import sys

import numpy as np

from scene import Network, images_nchw, mean_se, scenes


def abs_rel(pred, true):
    valid = true > 0
    pred, true = pred[valid], true[valid]
    pred = pred * np.median(true / pred)
    return float(np.mean(np.abs(pred - true) / true))


def log_slope(pred, true):
    valid = true > 0
    x, y = np.log(true[valid]), np.log(pred[valid])
    x, y = x - x.mean(), y - y.mean()
    return float((x * y).sum() / (x * x).sum())


def patch_rays(cameras, size, patch, k, scale):
    """`[N, (size / patch)², 6·k²]` Plücker rays of `cameras` (`scene.Camera`s at `size` pixels a
    side) in the first camera's frame, centres over `scale`, as `proto::rays::patch_rays`."""
    grid = size // patch
    # The sub-pixel centres patch by patch (row-major), k × k within each (row-major).
    sub = (np.arange(k) + 0.5) * patch / k
    along = (np.arange(grid)[:, None] * patch + sub[None, :]).ravel()
    v, u = (a.reshape(grid, k, grid, k).transpose(0, 2, 1, 3).ravel() for a in np.meshgrid(along, along, indexing="ij"))
    r0, t0 = cameras[0].rotation, cameras[0].translation
    out = []
    for c in cameras:
        origin = (r0 @ c.center() + t0) / scale
        d = np.stack([(u - c.cx) / c.fx, (v - c.cy) / c.fy, np.ones_like(u)], 1) @ (r0 @ c.rotation.T).T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        m = np.cross(origin[None, :], d)
        out.append(np.concatenate([d, m], 1).reshape(grid * grid, 6 * k * k))
    return np.stack(out).astype(np.float32)


def main(model, data, views="8", *flags):
    net = Network(model)
    with_rays = "--rays" in flags
    first = next((int(f.split("=", 1)[1]) for f in flags if f.startswith("--first=")), None)
    if with_rays and net.rays is None:
        sys.exit(f"{model}: --rays needs a file with a `rays` input")

    def depth(images, cameras, scale):
        size = images.shape[-1]
        rays = patch_rays(cameras, size, size // net.grid, net.k, scale) if with_rays else None
        return net.run(["depth"], images, rays)[0][:, 0]

    rows, per_scene = [], []
    for scene in scenes(data):
        chosen = list(range(len(scene)))[:first] if first else scene.context(views)
        images = images_nchw(scene, chosen)
        truth = [scene.depth(i) for i in chosen]
        size = images.shape[-1]
        cameras = [scene.camera(i).scaled_to(size, size) for i in chosen]
        scale = float(np.median(np.concatenate([t[t > 0] for t in truth])))
        together = depth(images, cameras, scale)
        alone = np.stack([depth(images[v : v + 1], cameras[v : v + 1], scale)[0] for v in range(len(chosen))])
        flat = lambda preds: np.concatenate([p.ravel() for p in preds])
        per_scene.append((abs_rel(flat(together), flat(truth)), abs_rel(flat(alone), flat(truth))))
        for t, a, g in zip(together, alone, truth):
            rows.append((abs_rel(t, g), abs_rel(a, g), log_slope(t, g), log_slope(a, g), float(np.median(np.abs(np.log(t / a))))))
    r = np.asarray(rows)
    s = np.asarray(per_scene)
    chosen = f"the first {first} frames" if first else f"the {views}-view context sets"
    print(f"{len(s)} scenes, {len(r)} views of {chosen}, {'true cameras as rays' if with_rays else 'no rays'}")
    print(f"AbsRel, each view at its own median scale: together {r[:, 0].mean():.4f}, alone {r[:, 1].mean():.4f}, together − alone {mean_se(r[:, 0] - r[:, 1])}")
    print(f"AbsRel, each scene at its own median scale: together {s[:, 0].mean():.4f}, alone {s[:, 1].mean():.4f}, together − alone {mean_se(s[:, 0] - s[:, 1])}")
    print(f"slope of log predicted on log true depth within a view: together {r[:, 2].mean():.3f}, alone {r[:, 3].mean():.3f}")
    print(f"median |log(together / alone)| per view, mean over views: {r[:, 4].mean():.4f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
