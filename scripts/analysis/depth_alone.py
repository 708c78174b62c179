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
import json
import os
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image


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


def mean_se(values):
    v = np.asarray(values)
    return f"{v.mean():+.4f} ± {v.std(ddof=1) / np.sqrt(len(v)):.4f}"


def gl_to_cv(c2w_rows):
    """World → camera rotation and translation (OpenCV axes) of a nerfstudio camera-to-world."""
    c2w = np.asarray(c2w_rows, np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
    rotation = c2w[:3, :3].T
    return rotation, -rotation @ c2w[:3, 3]


def camera(meta, frame, size):
    """(rotation, translation, fx, fy, cx, cy) of `frame` at `size` pixels a side: its own
    intrinsics, else the file's."""
    at = lambda key: frame.get(key, meta.get(key))
    sx, sy = size / at("w"), size / at("h")
    return gl_to_cv(frame["transform_matrix"]) + (at("fl_x") * sx, at("fl_y") * sy, at("cx") * sx, at("cy") * sy)


def patch_rays(cameras, size, patch, k, scale):
    """`[N, (size / patch)², 6·k²]` Plücker rays of `cameras` (as `camera` gives them) in the
    first camera's frame, centres over `scale`, as `proto::rays::patch_rays`."""
    grid = size // patch
    # The sub-pixel centres patch by patch (row-major), k × k within each (row-major).
    sub = (np.arange(k) + 0.5) * patch / k
    along = (np.arange(grid)[:, None] * patch + sub[None, :]).ravel()
    v, u = (a.reshape(grid, k, grid, k).transpose(0, 2, 1, 3).ravel() for a in np.meshgrid(along, along, indexing="ij"))
    r0, t0 = cameras[0][:2]
    out = []
    for rotation, translation, fx, fy, cx, cy in cameras:
        origin = (r0 @ (-rotation.T @ translation) + t0) / scale
        d = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], 1) @ (r0 @ rotation.T).T
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        m = np.cross(origin[None, :], d)
        out.append(np.concatenate([d, m], 1).reshape(grid * grid, 6 * k * k))
    return np.stack(out).astype(np.float32)


def main(model, data, views="8", *flags):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    with_rays = "--rays" in flags
    first = next((int(f.split("=", 1)[1]) for f in flags if f.startswith("--first=")), None)
    ray_shape = {i.name: i.shape for i in session.get_inputs()}.get("rays")
    if with_rays and ray_shape is None:
        sys.exit(f"{model}: --rays needs a file with a `rays` input")
    if ray_shape is not None:
        tokens, channels = ray_shape[1:]
        grid, k = round(np.sqrt(tokens)), round(np.sqrt(channels / 6))

    def depth(images, cameras, scale):
        feed = {"images": images}
        if with_rays:
            feed["rays"] = patch_rays(cameras, images.shape[-1], images.shape[-1] // grid, k, scale)
        elif ray_shape is not None:
            feed["rays"] = np.zeros((len(images), tokens, channels), np.float32)
        return session.run(["depth"], feed)[0][:, 0]
    rows, scenes = [], []
    for name in sorted(n for n in os.listdir(data) if n.startswith("scene_")):
        root = os.path.join(data, name)
        meta = json.load(open(os.path.join(root, "transforms.json")))
        frames = meta["frames"][:first] if first else [meta["frames"][i] for i in meta["eval"]["context"][views]]
        rgb = lambda f: np.asarray(Image.open(os.path.join(root, f["file_path"])).convert("RGB"), np.float32) / 255
        images = np.stack([rgb(f).transpose(2, 0, 1) for f in frames])
        truth = [np.asarray(Image.open(os.path.join(root, f["depth_file_path"])), np.float32) * meta["depth_unit_m"] for f in frames]
        cameras = [camera(meta, f, images.shape[-1]) for f in frames]
        scale = float(np.median(np.concatenate([t[t > 0] for t in truth])))
        together = depth(images, cameras, scale)
        alone = np.stack([depth(images[v : v + 1], cameras[v : v + 1], scale)[0] for v in range(len(frames))])
        flat = lambda preds: np.concatenate([p.ravel() for p in preds])
        scenes.append((abs_rel(flat(together), flat(truth)), abs_rel(flat(alone), flat(truth))))
        for t, a, g in zip(together, alone, truth):
            rows.append((abs_rel(t, g), abs_rel(a, g), log_slope(t, g), log_slope(a, g), float(np.median(np.abs(np.log(t / a))))))
    r = np.asarray(rows)
    s = np.asarray(scenes)
    chosen = f"the first {first} frames" if first else f"the {views}-view context sets"
    print(f"{len(s)} scenes, {len(r)} views of {chosen}, {'true cameras as rays' if with_rays else 'no rays'}")
    print(f"AbsRel, each view at its own median scale: together {r[:, 0].mean():.4f}, alone {r[:, 1].mean():.4f}, together − alone {mean_se(r[:, 0] - r[:, 1])}")
    print(f"AbsRel, each scene at its own median scale: together {s[:, 0].mean():.4f}, alone {s[:, 1].mean():.4f}, together − alone {mean_se(s[:, 0] - s[:, 1])}")
    print(f"slope of log predicted on log true depth within a view: together {r[:, 2].mean():.3f}, alone {r[:, 3].mean():.3f}")
    print(f"median |log(together / alone)| per view, mean over views: {r[:, 4].mean():.4f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
