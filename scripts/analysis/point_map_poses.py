#!/usr/bin/env python3
"""Has a network with a point-map head learned where the views stand? Each context set of a
dataset's scenes is run through an exported model (one with the optional `point_map` output)
with ONNX Runtime. For every view after the first, the pose that carries its own points (the
predicted depth along its true rays) onto its predicted point map (in view 0's frame) is found
by least squares (Kabsch), and its rotation is compared with the true one. Printed beside it:
the camera head's rotation error and that of the identity (what a head that learned nothing
scores), and the point map's distance to the true points over the scene's median depth,
against that of the view's own points left where they are (the identity again), with the
predicted depth (what a point map that knows no pose scores) and with the true one.

A measurement for the model card, not part of the product or of CI:
    pip install onnxruntime numpy pillow
    python3 scripts/analysis/point_map_poses.py runs/pm/pm1.onnx data/val40 [views] [--offsets]

--offsets: the model was trained with `--point-map-offsets`, so its point map is each point's
displacement from its own camera frame, added here to the view's own points.
views: a view count of the scenes' evaluation context sets (8), or `runN`: the first N
consecutive frames of each scene (the overlapping views of `--view-window`).
"""
import json
import os
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image

# nerfstudio (OpenGL axes) → OpenCV axes, applied to a camera-to-world matrix's columns.
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def angle_deg(r):
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))


def quat_matrix(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def kabsch(source, target):
    """Rotation R and translation t minimizing Σ |R·s + t − target|²; points as rows."""
    cs, ct = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, d]) @ u.T
    return r, ct - r @ cs


def rays(meta):
    h, w = meta["h"], meta["w"]
    v, u = np.mgrid[0:h, 0:w] + 0.5
    return np.stack([(u - meta["cx"]) / meta["fl_x"], (v - meta["cy"]) / meta["fl_y"], np.ones((h, w))], -1)


def main(model, data, views="8", offsets=False):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    rows = []
    for name in sorted(n for n in os.listdir(data) if n.startswith("scene_")):
        root = os.path.join(data, name)
        meta = json.load(open(os.path.join(root, "transforms.json")))
        chosen = range(int(views[3:])) if views.startswith("run") else meta["eval"]["context"][views]
        frames = [meta["frames"][i] for i in chosen]
        rgb = lambda f: np.asarray(Image.open(os.path.join(root, f["file_path"])).convert("RGB"), np.float32) / 255
        images = np.stack([rgb(f).transpose(2, 0, 1) for f in frames])
        camera, depth, points = session.run(["camera", "depth", "point_map"], {"images": images})
        truth = [np.asarray(Image.open(os.path.join(root, f["depth_file_path"])), np.float64) * meta["depth_unit_m"] for f in frames]
        c2w = [np.asarray(f["transform_matrix"]) @ GL_TO_CV for f in frames]
        ray = rays(meta)
        scale = np.median(np.concatenate([t[t > 0] for t in truth]))
        to_first = np.linalg.inv(c2w[0])
        for v in range(1, len(frames)):
            rel = to_first @ c2w[v]  # view v's camera → view 0's camera
            valid = truth[v] > 0
            own = (ray * depth[v, 0][..., None])[valid]
            mapped = points[v].transpose(1, 2, 0)[valid] + (own if offsets else 0)
            true_points = (ray * truth[v][..., None])[valid] @ rel[:3, :3].T + rel[:3, 3]
            r, _ = kabsch(own, mapped)
            head = quat_matrix(camera[v, 3:7]).T  # world→camera rotation, transposed: camera→world
            rows.append((
                angle_deg(r.T @ rel[:3, :3]),
                angle_deg(head.T @ rel[:3, :3]),
                angle_deg(rel[:3, :3]),
                float(np.linalg.norm(mapped - true_points, axis=1).mean() / scale),
                float(np.linalg.norm(own - true_points, axis=1).mean() / scale),
                float(np.linalg.norm((ray * truth[v][..., None])[valid] - true_points, axis=1).mean() / scale),
            ))
    r = np.asarray(rows)
    print(f"{len(r)} views (after the first) of {views} context sets")
    print("rotation error, degrees (mean / median): "
          f"point map {r[:, 0].mean():.2f} / {np.median(r[:, 0]):.2f}, "
          f"camera head {r[:, 1].mean():.2f} / {np.median(r[:, 1]):.2f}, "
          f"identity {r[:, 2].mean():.2f} / {np.median(r[:, 2]):.2f}")
    print(f"point map error / median depth: {r[:, 3].mean():.3f}; the view's own points unmoved: {r[:, 4].mean():.3f} "
          f"(predicted depth), {r[:, 5].mean():.3f} (true depth)")
    near = r[:, 2] < 30
    for name, part in [("within 30° of view 0", near), ("beyond", ~near)]:
        if part.any():
            print(f"views {name} ({part.sum()}): point map {r[part, 0].mean():.2f}°, camera head {r[part, 1].mean():.2f}°, "
                  f"identity {r[part, 2].mean():.2f}°")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--offsets"]
    main(*args, offsets="--offsets" in sys.argv[1:])
