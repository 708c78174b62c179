#!/usr/bin/env python3
"""Would resting the objects on the floor fix their depth? The network's depth regresses toward
each view's mean, so near objects come out too far and their bottoms sink below the floor. Each
8-view context set of a dataset's scenes is run through an exported model with ONNX Runtime
(one with the `rays` input reads none: the pipeline's first pass).
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
import sys

import numpy as np

from scene import Network, images_nchw, mean_se, scenes

# The camera's up, OpenCV axes (y down).
UP = np.array([0.0, -1.0, 0.0])


def plane_through(points, up):
    """Least-squares plane (normal toward `up`, offset) through the points."""
    mean = points.mean(0)
    normal = np.linalg.svd(points - mean)[2][2]
    normal = normal if normal @ up >= 0 else -normal
    return normal, -normal @ mean


def floor_plane(points, lower, threshold, rng, iterations=300, max_tilt=50.0):
    """RANSAC: three points of the lower half, scored +2 a point on the plane and -1 below it."""
    scored = points[::4]
    best, best_score = None, -np.inf
    for _ in range(iterations):
        a, b, c = lower[rng.choice(len(lower), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-9:
            continue
        n = n / np.linalg.norm(n)
        n = n if n @ UP >= 0 else -n
        offset = -n @ a
        if n @ UP < np.cos(np.radians(max_tilt)) or offset <= 0:
            continue
        h = scored @ n + offset
        score = 2 * (np.abs(h) < threshold).sum() - (h < -threshold).sum()
        if score > best_score:
            best, best_score = (n, offset), score
    n, offset = best
    return plane_through(points[np.abs(points @ n + offset) < threshold], UP)


def abs_rel(pred, true, where):
    return float(np.mean(np.abs(pred[where] - true[where]) / true[where]))


def main(model, data, percentile="2", floor="plane"):
    percentile = float(percentile)
    net = Network(model)
    rng = np.random.default_rng(1)
    rows = []
    for scene in scenes(data):
        chosen = scene.context(8)
        depths = net.run(["depth"], images_nchw(scene, chosen))[0][:, 0]
        height, width = depths.shape[1:]
        for i, d in zip(chosen, depths):
            camera = scene.camera(i).scaled_to(width, height)
            ray = camera.rays()
            true = scene.depth(i)
            ids = scene.instances(i)
            valid = true > 0
            world_y = (ray * true[..., None]) @ camera.rotation[:, 1] + camera.center()[1]
            true_floor = valid & (ids == 0) & (world_y < 0.03)
            if true_floor.sum() < 200:
                continue
            points = ray * d[..., None]
            if floor == "gt":
                n, offset = plane_through(points[true_floor], UP)
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
        print(f"AbsRel {name}: {r[:, col].mean():.4f} -> {r[:, col + 1].mean():.4f}, paired {mean_se(r[:, col + 1] - r[:, col])}")


if __name__ == "__main__":
    main(*sys.argv[1:])
