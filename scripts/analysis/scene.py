"""The one reader of a scene folder for the analysis scripts: its nerfstudio `transforms.json`
(cameras, depth unit, evaluation split) and each frame's image, depth and instance mask, and
the exported network as the scripts run it with ONNX Runtime. Import it from a script in this
folder (`from scene import Network, scenes`); it is not a script itself.

It follows the Rust reader, which is the truth for the format and its conventions
(`proto/src/dataset/read.rs`, `transforms.rs`, `proto/src/camera.rs`):

- `transform_matrix` is a camera-to-world matrix, row-major, OpenGL axes (x right, y up,
  looking down −z). Inside, every camera is OpenCV's (x right, y down, +z forward) as a
  world-to-camera rotation and translation, `x_cam = R x_world + t`; the conversion flips
  the camera's y and z axes (`Camera::from_nerfstudio`) and is made in `from_nerfstudio`
  here and nowhere else. A rotation part that carries scale is divided by it.
- Intrinsics (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`) are a frame's own where it has them,
  else the file's; pixel centres sit at +0.5.
- Depth PNGs are 16-bit, times `depth_unit_m` (default 0.001) metres along the camera's z
  axis, 0 where nothing was hit; instance masks are 16-bit ids, 0 for none.
- `eval.context` maps a view count ("8") to the input frames (`eval.target`, the frames never
  input, no script here reads).

It validates less than the Rust reader (the scenes it reads were written or checked by it).
"""
import json
import os
from dataclasses import dataclass, replace

import numpy as np
from PIL import Image

DEFAULT_DEPTH_UNIT_M = 0.001
# OpenGL camera axes ↔ OpenCV camera axes (its own inverse), applied to a camera-to-world
# matrix's columns.
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """A pinhole camera as `proto::camera::Camera`: world → camera `rotation` (3×3) and
    `translation` (OpenCV axes), intrinsics in pixels for an image of `width` × `height`."""

    rotation: np.ndarray
    translation: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def center(self):
        """The camera's centre in world coordinates."""
        return -self.rotation.T @ self.translation

    def scaled_to(self, width, height):
        """The same camera at another image size (the intrinsics scale with the image)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=width, height=height)

    def rays(self):
        """`[h, w, 3]`: each pixel centre's camera-space point at z = 1 (multiply by a depth map
        for the points it sees)."""
        v, u = np.mgrid[0 : self.height, 0 : self.width] + 0.5
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones((self.height, self.width))], -1)

    def project(self, points):
        """Camera-space points (rows) → pixel positions u, v and depth z."""
        z = points[..., 2]
        return points[..., 0] / z * self.fx + self.cx, points[..., 1] / z * self.fy + self.cy, z


def from_nerfstudio(c2w_rows, fx, fy, cx, cy, width, height):
    """A `Camera` from a nerfstudio (OpenGL) camera-to-world matrix given row-major, as stored in
    `transforms.json`: `Camera::from_nerfstudio`."""
    cv_c2w = np.asarray(c2w_rows, np.float64) @ GL_FROM_CV
    linear = cv_c2w[:3, :3]
    # glam's to_scale_rotation_translation: the columns' lengths, x's signed by the determinant.
    scale = np.linalg.norm(linear, axis=0) * np.array([np.sign(np.linalg.det(linear)), 1.0, 1.0])
    rotation = (linear / scale).T
    return Camera(rotation, -rotation @ cv_c2w[:3, 3], fx, fy, cx, cy, width, height)


INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


def camera_of(record, defaults=None, where="camera"):
    """The camera of a record with a `transform_matrix` and intrinsics: a `transforms.json`
    frame (its own intrinsics, else those of `defaults`, the file), or a camera of
    `inssplat reconstruct --json`. `where` names the record in errors."""
    defaults = defaults or {}
    k = []
    for key in INTRINSICS:
        value = record.get(key)
        value = defaults.get(key) if value is None else value
        if value is None:
            raise KeyError(f"{where}.{key} missing (no per-frame or top-level `{key}`)")
        k.append(value)
    return from_nerfstudio(record["transform_matrix"], *k)


class Scene:
    """One scene folder: `meta` is its parsed `transforms.json`, `frames` its frame records.
    Frames are named by their index in the file."""

    def __init__(self, root):
        self.root = root
        self.name = os.path.basename(os.path.normpath(root))
        with open(os.path.join(root, "transforms.json")) as f:
            self.meta = json.load(f)
        self.frames = self.meta["frames"]
        self.depth_unit_m = self.meta.get("depth_unit_m", DEFAULT_DEPTH_UNIT_M)

    def __len__(self):
        return len(self.frames)

    def context(self, views):
        """The frame indices of the evaluation context set for `views` input views."""
        return list(self.meta["eval"]["context"][str(views)])

    def camera(self, i):
        """Frame i's camera (OpenCV axes, world → camera) at the file's image size."""
        return camera_of(self.frames[i], self.meta, f"{self.root}/transforms.json: frames[{i}]")

    def path(self, i, key="file_path"):
        """The file frame i names under `key` (file_path, depth_file_path, instance_file_path)."""
        return os.path.join(self.root, self.frames[i][key])

    def image(self, i):
        """Frame i's RGB image, `[h, w, 3]` float32 in [0, 1]."""
        return np.asarray(Image.open(self.path(i)).convert("RGB"), np.float32) / 255

    def depth(self, i, dtype=np.float32):
        """Frame i's true depth in metres, `[h, w]`, 0 where nothing was hit."""
        raw = np.asarray(Image.open(self.path(i, "depth_file_path")), np.float64)
        return (raw * self.depth_unit_m).astype(dtype)

    def instances(self, i):
        """Frame i's true instance ids, `[h, w]`, 0 for none."""
        return np.asarray(Image.open(self.path(i, "instance_file_path")))


def scenes(data):
    """The scenes of a dataset folder (its `scene_*` folders), in order."""
    return [Scene(os.path.join(data, name)) for name in sorted(n for n in os.listdir(data) if n.startswith("scene_"))]


def images_nchw(scene, indices):
    """The frames' images as the network's `images` input, `[n, 3, h, w]` float32."""
    return np.stack([scene.image(i).transpose(2, 0, 1) for i in indices])


class Network:
    """An exported model run with ONNX Runtime on the CPU (`threads` threads). `rays` is the shape
    `(tokens, channels)` of its optional `rays` input, None without one; then `grid` is its
    patches a side and `k` its rays a patch side (`6·k²` channels)."""

    def __init__(self, model, threads=2):
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        self.session = ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])
        shape = {i.name: i.shape for i in self.session.get_inputs()}.get("rays")
        self.rays = None if shape is None else tuple(shape[1:])
        if self.rays is not None:
            tokens, channels = self.rays
            self.grid, self.k = round(np.sqrt(tokens)), round(np.sqrt(channels / 6))

    def run(self, outputs, images, rays=None):
        """The named outputs for `images` (`[n, 3, h, w]`); a network with the `rays` input reads
        `rays`, or zeros without them (no cameras: the pipeline's first pass)."""
        feed = {"images": images}
        if self.rays is not None:
            feed["rays"] = np.zeros((len(images), *self.rays), np.float32) if rays is None else rays
        return self.session.run(outputs, feed)


def mean_se(values):
    """`+mean ± standard error` of paired differences, as the model card gives them."""
    v = np.asarray(values)
    return f"{v.mean():+.4f} ± {v.std(ddof=1) / np.sqrt(len(v)):.4f}"
