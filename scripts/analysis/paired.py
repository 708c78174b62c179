#!/usr/bin/env python3
"""Paired per-scene differences between two `inssplat-eval score --out` runs on the same scenes.

    python3 scripts/analysis/paired.py BASE/eval.json NEW/eval.json [metric ...]

For every metric, and every view count both runs scored, prints the mean of NEW − BASE over
the scenes both scored and its standard error (the model card's "± s.e." figures), with
the two runs' own means. Percentages are printed in points (×100), as the card gives them.
"""
import json
import math
import sys

DEFAULT = [
    "instance_miou", "instance_acc25", "instance_pq", "t_miou", "t_sr50", "context_instance_miou", "semantic_miou",
    "query_iou", "psnr", "ssim", "depth_abs_rel", "rotation_deg", "instances_found", "seconds",
]
# Metrics reported in [0, 1] that the card gives in points.
POINTS = {"instance_miou", "instance_acc25", "instance_pq", "t_miou", "t_sr50", "context_instance_miou",
          "context_ceiling_miou", "semantic_miou", "semantic_macc", "query_iou"}


def scores(path):
    with open(path) as f:
        report = json.load(f)
    return {(s["scene"], s["views"]): s for s in report["scenes"]}


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    base, new = scores(sys.argv[1]), scores(sys.argv[2])
    metrics = sys.argv[3:] or DEFAULT
    keys = sorted(set(base) & set(new))
    if not keys:
        sys.exit("the two runs share no (scene, views) pair")
    views = sorted({v for _, v in keys})
    print(f"{len(keys)} scene evaluations in both; NEW − BASE, mean ± s.e.")
    print("| views | metric | base | new | new − base |")
    print("|---|---|---|---|---|")
    for v in views + ["all"]:
        chosen = [k for k in keys if v == "all" or k[1] == v]
        if v == "all" and len(views) == 1:
            continue
        for m in metrics:
            pairs = [(base[k].get(m), new[k].get(m)) for k in chosen]
            pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
            if len(pairs) < 2:
                continue
            scale = 100.0 if m in POINTS else 1.0
            d = [(b - a) * scale for a, b in pairs]
            mean = sum(d) / len(d)
            se = math.sqrt(sum((x - mean) ** 2 for x in d) / (len(d) - 1) / len(d))
            a = sum(p[0] for p in pairs) * scale / len(pairs)
            b = sum(p[1] for p in pairs) * scale / len(pairs)
            print(f"| {v} | {m} | {a:.4g} | {b:.4g} | {mean:+.3g} ± {se:.2g} |")


if __name__ == "__main__":
    main()
