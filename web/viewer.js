// The 3D view: the Gaussians drawn by Spark (a three.js splat renderer) from scene.ply, the
// input cameras as frustums, orbit controls. Colours are per Gaussian: the file's own, or any
// the page computes (instances, a highlight), given as RGBA bytes in the file's order.

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { RgbaArray, SparkRenderer, SplatMesh } from "@sparkjsdev/spark";
import { BACKGROUND } from "./colours.js";

export class Viewer {
  constructor(canvas) {
    this.canvas = canvas;
    this.renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
    this.renderer.setClearColor(BACKGROUND);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(60, 1, 0.01, 1000);
    // Frames are drawn only when something changed (the view, the colours, or Spark's sort
    // finishing): a software-rendered browser stays responsive.
    this.dirty = true;
    this.scene.add(new SparkRenderer({ renderer: this.renderer, onDirty: () => (this.dirty = true) }));
    this.controls = null;
    this.cameras = new THREE.Group();
    this.scene.add(this.cameras);
    this.splats = null;
    this.renderer.setAnimationLoop(() => this.frame());
  }

  frame() {
    const { clientWidth: w, clientHeight: h } = this.canvas;
    if (w && h && (this.canvas.width !== w || this.canvas.height !== h)) {
      this.renderer.setSize(w, h, false);
      this.camera.aspect = w / h;
      this.camera.updateProjectionMatrix();
      this.dirty = true;
    }
    this.controls?.update();
    if (!this.dirty) return;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
  }

  /** Shows the Gaussians of `plyBytes` (`gaussians` from ply.js) seen by `cameras`
   * (nerfstudio camera-to-world, OpenGL axes); the view starts behind the first camera. */
  async show(plyBytes, gaussians, cameras) {
    if (this.splats) {
      this.scene.remove(this.splats);
      this.splats.dispose();
    }
    this.splats = new SplatMesh({ fileBytes: plyBytes, fileName: "scene.ply" });
    this.scene.add(this.splats);
    await this.splats.initialized;
    this.colours = new RgbaArray({ array: new Uint8Array(gaussians.rgba), count: gaussians.count });
    this.splats.splatRgba = this.colours;
    this.splats.updateGenerator();
    this.drawCameras(cameras, gaussians.radius * 0.25);
    this.lookFrom(cameras[0], gaussians);
  }

  /** Paints every Gaussian with `rgba` (4 bytes each, the file's order). */
  setColours(rgba) {
    this.colours.array.set(rgba);
    this.colours.needsUpdate = true;
    this.splats.needsUpdate = true;
    this.dirty = true;
  }

  showCameras(visible) {
    this.cameras.visible = visible;
    this.dirty = true;
  }

  drawCameras(cameras, depth) {
    this.cameras.clear();
    const material = new THREE.LineBasicMaterial({ color: 0xffc400 });
    for (const cam of cameras) {
      const x = (cam.w / 2 / cam.fl_x) * depth;
      const y = (cam.h / 2 / cam.fl_y) * depth;
      const corners = [[-x, -y], [x, -y], [x, y], [-x, y]].map(([a, b]) => new THREE.Vector3(a, b, -depth));
      const o = new THREE.Vector3();
      const points = corners.flatMap((c, i) => [o, c, c, corners[(i + 1) % 4]]);
      const frustum = new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(points), material);
      frustum.matrixAutoUpdate = false;
      frustum.matrix.set(...cam.transform_matrix.flat());
      this.cameras.add(frustum);
    }
  }

  /** Puts the view a little behind `cam`, looking at the centre of the Gaussians. */
  lookFrom(cam, gaussians) {
    const pose = new THREE.Matrix4().set(...cam.transform_matrix.flat());
    const position = new THREE.Vector3().setFromMatrixPosition(pose);
    const up = new THREE.Vector3(0, 1, 0).transformDirection(pose);
    const back = new THREE.Vector3(0, 0, 1).transformDirection(pose);
    this.camera.fov = THREE.MathUtils.radToDeg(2 * Math.atan(cam.h / 2 / cam.fl_y));
    this.camera.up.copy(up);
    this.camera.position.copy(position).addScaledVector(back, gaussians.radius * 0.6);
    this.camera.updateProjectionMatrix();
    // OrbitControls orbits about the camera's up as it is when they are made.
    this.controls?.dispose();
    this.controls = new OrbitControls(this.camera, this.canvas);
    this.controls.addEventListener("change", () => (this.dirty = true));
    this.controls.target.set(...gaussians.centre);
    this.controls.update();
    this.dirty = true;
  }
}
