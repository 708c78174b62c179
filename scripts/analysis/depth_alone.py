#!/usr/bin/env python3
"""Does the network's depth use the other views? Each 8-view context set of a dataset's scenes
is run through an exported model twice with ONNX Runtime: all 8 views together, and each view
alone. Prints the depth AbsRel of both (each view at its own median scale, and each scene at
its own), the paired difference, the within-view slope of log predicted on log true depth,
and how much the two predictions differ.

A measurement for the model card, not part of the product or of CI:
    pip install onnxruntime numpy pillow
    python3 scripts/analysis/depth_alone.py models/inssplat-default.onnx data/val40
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


def main(model, data, views="8"):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 2
    session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
    depth = lambda images: session.run(["depth"], {"images": images})[0][:, 0]
    rows, scenes = [], []
    for name in sorted(n for n in os.listdir(data) if n.startswith("scene_")):
        root = os.path.join(data, name)
        meta = json.load(open(os.path.join(root, "transforms.json")))
        frames = [meta["frames"][i] for i in meta["eval"]["context"][views]]
        rgb = lambda f: np.asarray(Image.open(os.path.join(root, f["file_path"])).convert("RGB"), np.float32) / 255
        images = np.stack([rgb(f).transpose(2, 0, 1) for f in frames])
        truth = [np.asarray(Image.open(os.path.join(root, f["depth_file_path"])), np.float32) * meta["depth_unit_m"] for f in frames]
        together = depth(images)
        alone = np.stack([depth(images[v : v + 1])[0] for v in range(len(frames))])
        flat = lambda preds: np.concatenate([p.ravel() for p in preds])
        scenes.append((abs_rel(flat(together), flat(truth)), abs_rel(flat(alone), flat(truth))))
        for t, a, g in zip(together, alone, truth):
            rows.append((abs_rel(t, g), abs_rel(a, g), log_slope(t, g), log_slope(a, g), float(np.median(np.abs(np.log(t / a))))))
    r = np.asarray(rows)
    s = np.asarray(scenes)
    print(f"{len(s)} scenes, {len(r)} views of {views}")
    print(f"AbsRel, each view at its own median scale: together {r[:, 0].mean():.4f}, alone {r[:, 1].mean():.4f}, together − alone {mean_se(r[:, 0] - r[:, 1])}")
    print(f"AbsRel, each scene at its own median scale: together {s[:, 0].mean():.4f}, alone {s[:, 1].mean():.4f}, together − alone {mean_se(s[:, 0] - s[:, 1])}")
    print(f"slope of log predicted on log true depth within a view: together {r[:, 2].mean():.3f}, alone {r[:, 3].mean():.3f}")
    print(f"median |log(together / alone)| per view, mean over views: {r[:, 4].mean():.4f}")


if __name__ == "__main__":
    main(*sys.argv[1:])
