#!/usr/bin/env python3
"""Would resting the objects on the floor fix their depth? The network's depth regresses toward
each view's mean, so near objects come out too far and their bottoms sink below the floor. Each
8-view context set of a dataset's scenes is run through an exported model with ONNX Runtime.
Each view's floor is a plane fitted to its predicted depth: RANSAC over the lower half of the
view, the normal within 50° of the camera's up, the most points within 3% of the median depth
and the fewest below (or, with `gt`, fitted to the true floor's pixels). Every true object
(from the true instance masks) whose low point (the percentile given) lies below that plane is
then moved toward the camera along its rays until that point lies on it. Prints the depth
AbsRel of the objects' pixels and of the shell's, each view at its own median scale, before and
after, with the paired difference.

An upper bound for the model card (the true masks say which pixels are one object), not part
of the product or of CI:
    pip install onnxruntime numpy pillow
    python3 scripts/analysis/floor_contact.py models/inssplat-default.onnx data/val40 [2] [plane|gt]
"""
import json
import os
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image


def plane_through(points, up):
    """Least-squares plane (normal toward `up`, offset) through the points."""
    mean = points.mean(0)
    normal = np.linalg.svd(points - mean)[2][2]
    normal = normal if normal @ up >= 0 else -normal
    return normal, -normal @ mean


def floor_plane(points, lower, threshold, rng, iterations=300, max_tilt=50.0):
    """RANSAC: three points of the lower half, scored +2 a point on the plane and -1 below it."""
    up = np.array([0.0, 1.0, 0.0])  # OpenGL camera axes: y up
    scored = points[::4]
    best, best_score = None, -np.inf
    for _ in range(iterations):
        a, b, c = lower[rng.choice(len(lower), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-9:
            continue
        n = n / np.linalg.norm(n)
        n = n if n @ up >= 0 else -n
        offset = -n @ a
        if n @ up < np.cos(np.radians(max_tilt)) or offset <= 0:
            continue
        h = scored @ n + offset
        score = 2 * (np.abs(h) < threshold).sum() - (h < -threshold).sum()
        if score > best_score:
            best, best_score = (n, offset), score
    n, offset = best
    return plane_through(points[np.abs(points @ n + offset) < threshold], up)


def abs_rel(pred, true, where):
    return float(np.mean(np.abs(pred[where] - true[where]) / true[where]))


def main(model, data, percentile="2", floor="plane"):
    percentile = float(percentile)
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(1)
    rows = []
    for name in sorted(n for n in os.listdir(data) if n.startswith("scene_")):
        root = os.path.join(data, name)
        meta = json.load(open(os.path.join(root, "transforms.json")))
        frames = [meta["frames"][i] for i in meta["eval"]["context"]["8"]]
        read = lambda f, key: np.asarray(Image.open(os.path.join(root, f[key])))
        images = np.stack([read(f, "file_path")[..., :3].astype(np.float32).transpose(2, 0, 1) / 255 for f in frames])
        depths = session.run(["depth"], {"images": images})[0][:, 0]
        height, width = depths.shape[1:]
        u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        ray = np.stack([(u - meta["cx"]) / meta["fl_x"], -(v - meta["cy"]) / meta["fl_y"], -np.ones_like(u)], -1)
        for f, d in zip(frames, depths):
            true = read(f, "depth_file_path").astype(np.float32) * meta["depth_unit_m"]
            ids = read(f, "instance_file_path")
            valid = true > 0
            world_y = (ray * true[..., None]) @ np.array(f["transform_matrix"])[1, :3] + f["transform_matrix"][1][3]
            true_floor = valid & (ids == 0) & (world_y < 0.03)
            if true_floor.sum() < 200:
                continue
            points = ray * d[..., None]
            if floor == "gt":
                n, offset = plane_through(points[true_floor], np.array([0.0, 1.0, 0.0]))
            else:
                n, offset = floor_plane(points.reshape(-1, 3), points[height // 2 :].reshape(-1, 3), 0.03 * np.median(d), rng)
            height_above = points @ n + offset
            rested = d.copy()
            for k in np.unique(ids[valid & (ids > 0)]):
                mask = valid & (ids == k)
                if mask.sum() < 20:
                    continue
                h = height_above[mask]
                low = points[mask][np.argmin(np.abs(h - np.percentile(h, percentile)))]
                below = -(n @ low)
                if below > 1e-6 and offset / below < 1:
                    rested[mask] *= max(offset / below, 0.5)
            objects, shell = valid & (ids > 0), valid & (ids == 0)
            if not objects.any():
                continue
            at_scale = lambda p: p * np.median(true[valid] / p[valid])
            before, after = at_scale(d), at_scale(rested)
            rows.append([abs_rel(before, true, objects), abs_rel(after, true, objects), abs_rel(before, true, shell), abs_rel(after, true, shell)])
    r = np.asarray(rows)
    print(f"{len(r)} views with a floor and an object, low point at percentile {percentile:g}, floor: {floor}")
    for name, col in [("objects", 0), ("shell", 2)]:
        diff = r[:, col + 1] - r[:, col]
        print(f"AbsRel {name}: {r[:, col].mean():.4f} -> {r[:, col + 1].mean():.4f}, paired {diff.mean():+.4f} ± {diff.std(ddof=1) / np.sqrt(len(diff)):.4f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
