//! The CPU tile rasterizer against a naive per-pixel reference renderer (the oracle), the id
//! renderer against one-hot channels composited by the CPU rasterizer, and the wgpu
//! rasterizer against the CPU one. The reference is written independently of the crate's
//! code, in f64: it projects every Gaussian, sorts them by depth and composites every one at
//! every pixel, no tiles and no extents. Comparison per value: |got − want| ≤ 1e-5 +
//! 1e-2·|want|; NaN is reported on its own; a failure names the output, pixel and both values.

use glam::{DMat3, DQuat, DVec3, Quat, Vec3};
use inssplat_proto::{Camera, Intrinsics};
use inssplat_raster::render::{
    ALPHA_MAX, ALPHA_MIN, Backend, IdImage, Image, LOW_PASS, NEAR_PLANE, RenderError, Splats,
    T_MIN, render, render_any, render_ids, render_ids_any,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::support::Scene;

impl Scene {
    fn push(
        &mut self,
        mean: [f32; 3],
        log_scale: [f32; 3],
        rotation: [f32; 4],
        logit: f32,
        rng: &mut ChaCha8Rng,
    ) {
        self.means.push(mean);
        self.log_scales.push(log_scale);
        self.rotations.push(rotation);
        self.logits.push(logit);
        for _ in 0..self.channels {
            self.features.push(rng.random_range(-0.5..1.5));
        }
    }
}

fn camera(width: u32, height: u32) -> Camera {
    let k = Intrinsics::from_fov_y(width, height, 1.0);
    Camera::look_at(k, Vec3::new(0.3, -0.4, -3.0), Vec3::new(0.0, 0.1, 0.5), Vec3::Y)
}

/// `n` Gaussians spread over the camera's view at depths 1–6.
fn random_scene(n: usize, channels: usize, cam: &Camera, seed: u64) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut scene = Scene { channels, ..Default::default() };
    for _ in 0..n {
        let z = rng.random_range(1.0..6.0f32);
        let p_cam = Vec3::new(rng.random_range(-0.7..0.7) * z, rng.random_range(-0.6..0.6) * z, z);
        let mean = cam.camera_to_world(p_cam).to_array();
        let log_scale = [0; 3].map(|_| rng.random_range(-4.0..-1.0f32));
        let rotation = [0; 4].map(|_| rng.random_range(-2.0..2.0f32));
        let logit = rng.random_range(-3.0..4.0);
        scene.push(mean, log_scale, rotation, logit, &mut rng);
    }
    scene
}

struct Reference {
    features: Vec<f64>,
    depth: Vec<f64>,
    alpha: Vec<f64>,
}

struct RefGaussian {
    uv: [f64; 2],
    conic: [f64; 3],
    opacity: f64,
    z: f64,
    gid: usize,
}

/// The oracle: same math as the crate documents, in f64, every Gaussian at every pixel.
fn reference(s: &Splats, cam: &Camera, background: &[f32]) -> Reference {
    let k = cam.intrinsics;
    let (w, h) = (k.width as usize, k.height as usize);
    let (fx, fy, cx, cy) = (k.fx as f64, k.fy as f64, k.cx as f64, k.cy as f64);
    let view_rot = DMat3::from_quat(cam.rotation.as_dquat().normalize());
    let view_t = cam.translation.as_dvec3();
    let (tan_x, tan_y) = (0.5 * w as f64 / fx, 0.5 * h as f64 / fy);
    let lim_x = (cx / fx + 0.3 * tan_x, (w as f64 - cx) / fx + 0.3 * tan_x);
    let lim_y = (cy / fy + 0.3 * tan_y, (h as f64 - cy) / fy + 0.3 * tan_y);
    let c = s.channels;
    let mut gs = Vec::new();
    for i in 0..s.means.len() {
        let f = &s.features[i * c..(i + 1) * c];
        let finite = s.means[i]
            .iter()
            .chain(&s.log_scales[i])
            .chain(&s.rotations[i])
            .chain(f)
            .all(|v| v.is_finite());
        if !finite || !s.logit_opacity[i].is_finite() {
            continue;
        }
        let opacity = 1.0 / (1.0 + (-(s.logit_opacity[i] as f64)).exp());
        let p = view_rot * DVec3::from(s.means[i].map(f64::from)) + view_t;
        let q = s.rotations[i].map(f64::from);
        let qn = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if p.z < NEAR_PLANE as f64 || qn < 1e-12 || opacity < ALPHA_MIN as f64 {
            continue;
        }
        let r = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]) / qn);
        let sc = DMat3::from_diagonal(DVec3::from(s.log_scales[i].map(|v| (v as f64).exp())));
        let sigma_cam = view_rot * r * sc * sc * r.transpose() * view_rot.transpose();
        let tx = p.z * (p.x / p.z).clamp(-lim_x.0, lim_x.1);
        let ty = p.z * (p.y / p.z).clamp(-lim_y.0, lim_y.1);
        // J as a 3×3 with a zero last row: columns are d(u, v, 0)/d(x, y, z).
        let j = DMat3::from_cols(
            DVec3::new(fx / p.z, 0.0, 0.0),
            DVec3::new(0.0, fy / p.z, 0.0),
            DVec3::new(-fx * tx / (p.z * p.z), -fy * ty / (p.z * p.z), 0.0),
        );
        let cov = j * sigma_cam * j.transpose();
        let (a, b, cc) =
            (cov.x_axis.x + LOW_PASS as f64, cov.y_axis.x, cov.y_axis.y + LOW_PASS as f64);
        let det = a * cc - b * b;
        if det.is_nan() || det <= 0.0 {
            continue;
        }
        gs.push(RefGaussian {
            uv: [fx * p.x / p.z + cx, fy * p.y / p.z + cy],
            conic: [cc / det, -b / det, a / det],
            opacity,
            z: p.z,
            gid: i,
        });
    }
    gs.sort_by(|a, b| (a.z as f32).total_cmp(&(b.z as f32)).then(a.gid.cmp(&b.gid)));

    let pixels = w * h;
    let mut out = Reference {
        features: vec![0.0; c * pixels],
        depth: vec![0.0; pixels],
        alpha: vec![0.0; pixels],
    };
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            let mut t = 1.0f64;
            let mut acc = vec![0.0f64; c];
            let mut depth = 0.0;
            for g in &gs {
                let (dx, dy) = (px - g.uv[0], py - g.uv[1]);
                let [a, b, cc] = g.conic;
                let power = (-0.5 * (a * dx * dx + cc * dy * dy) - b * dx * dy).min(0.0);
                let v = g.opacity * power.exp();
                if v < ALPHA_MIN as f64 {
                    continue;
                }
                let alpha = v.min(ALPHA_MAX as f64);
                let next = t * (1.0 - alpha);
                if next < T_MIN as f64 {
                    break;
                }
                for (ch, a) in acc.iter_mut().enumerate() {
                    *a += alpha * t * s.features[g.gid * c + ch] as f64;
                }
                depth += alpha * t * g.z;
                t = next;
            }
            let pix = y * w + x;
            for (ch, a) in acc.iter().enumerate() {
                out.features[ch * pixels + pix] =
                    a + t * background.get(ch).map_or(0.0, |&b| b as f64);
            }
            out.alpha[pix] = 1.0 - t;
            out.depth[pix] = depth / (1.0 - t).max(1e-10);
        }
    }
    out
}

/// Per-value comparison of one image plane; panics naming the first bad pixel, both values
/// and how many are bad. NaN is reported on its own.
fn assert_close(what: &str, got: &[f32], want: &[f64], width: usize, atol: f64, rtol: f64) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let nan: Vec<usize> = (0..got.len()).filter(|&i| got[i].is_nan()).collect();
    if let Some(&i) = nan.first() {
        panic!("{what}: {} NaN values, first at pixel x={}, y={}", nan.len(), i % width, i / width);
    }
    let bad: Vec<usize> = (0..got.len())
        .filter(|&i| (got[i] as f64 - want[i]).abs() > atol + rtol * want[i].abs())
        .collect();
    if let Some(&i) = bad.first() {
        panic!(
            "{what}: {} of {} pixels differ beyond {atol:e} + {rtol:e}·|want|; first at x={}, y={}: got {}, want {}",
            bad.len(),
            got.len(),
            i % width,
            i / width,
            got[i],
            want[i]
        );
    }
}

fn compare_with_reference(scene: &Scene, cam: &Camera, background: &[f32]) -> Image {
    let (image, _) = render(&scene.splats(), cam, background).unwrap();
    let want = reference(&scene.splats(), cam, background);
    let w = cam.intrinsics.width as usize;
    let h = cam.intrinsics.height as usize;
    for ch in 0..scene.channels {
        let plane = ch * w * h..(ch + 1) * w * h;
        assert_close(
            &format!("channel {ch}"),
            &image.features[plane.clone()],
            &want.features[plane],
            w,
            1e-5,
            1e-2,
        );
    }
    assert_close("alpha", &image.alpha, &want.alpha, w, 1e-5, 1e-2);
    assert_close("depth", &image.depth, &want.depth, w, 1e-5, 1e-2);
    image
}

#[test]
fn cpu_matches_reference_on_random_scenes() {
    for (seed, (w, h, n, c)) in
        [(37, 29, 60, 3), (64, 48, 300, 11), (50, 70, 150, 1)].into_iter().enumerate()
    {
        let cam = camera(w, h);
        let scene = random_scene(n, c, &cam, seed as u64);
        let bg: Vec<f32> = (0..c).map(|i| 0.1 * i as f32).collect();
        let image = compare_with_reference(&scene, &cam, &bg);
        assert!(image.alpha.iter().any(|&a| a > 0.5), "scene {seed} should cover pixels");
    }
}

#[test]
fn cpu_matches_reference_on_dense_opaque_scene() {
    // Many opaque Gaussians: pixels saturate and stop early.
    let cam = camera(48, 40);
    let mut scene = random_scene(400, 4, &cam, 7);
    scene.logits.iter_mut().for_each(|l| *l = l.abs() + 3.0);
    scene.log_scales.iter_mut().for_each(|s| s.iter_mut().for_each(|v| *v += 1.5));
    let image = compare_with_reference(&scene, &cam, &[]);
    assert!(image.alpha.iter().filter(|&&a| a > 0.999).count() > 100, "want saturated pixels");
}

#[test]
fn cpu_matches_reference_on_edge_cases() {
    let cam = camera(40, 36);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut scene = random_scene(40, 3, &cam, 11);
    let world = |p: [f32; 3]| cam.camera_to_world(Vec3::from(p)).to_array();
    let q = [0.9, 0.2, -0.3, 0.1];
    // Behind the camera, large enough to cover the view if it were projected.
    scene.push(world([0.0, 0.0, -1.0]), [0.0; 3], q, 3.0, &mut rng);
    // Straddling the near plane: centre just in front, extent far behind.
    scene.push(world([0.05, 0.0, 0.02]), [-0.5, -1.0, -0.7], q, 2.0, &mut rng);
    // Centre nearer than the near plane: skipped.
    scene.push(world([0.0, 0.0, 0.5 * NEAR_PLANE]), [-2.0; 3], q, 2.0, &mut rng);
    // Huge (e^8 ≈ 3000 units) and tiny (e^-20) scales. (A huge scale next to a small one,
    // ratio beyond ~1e3, loses the thin axis to f32 rounding in Σ = M Mᵀ — as in gsplat — so
    // the huge one here is only mildly anisotropic.)
    scene.push(world([0.2, 0.1, 30.0]), [8.0, 7.5, 8.0], q, -2.0, &mut rng);
    scene.push(world([-0.3, 0.2, 2.0]), [-20.0; 3], q, 4.0, &mut rng);
    // Far outside the field of view (Jacobian clamped), big enough to reach into the image.
    scene.push(world([6.0, -1.0, 2.2]), [1.5, 1.0, 1.2], q, 1.0, &mut rng);
    // Zero and denormal quaternions: skipped.
    scene.push(world([0.0, 0.0, 2.0]), [-1.0; 3], [0.0; 4], 3.0, &mut rng);
    scene.push(world([0.1, 0.0, 2.0]), [-1.0; 3], [1e-40, 0.0, 0.0, 0.0], 3.0, &mut rng);
    // Unnormalized quaternion, large norm.
    scene.push(
        world([0.1, -0.2, 2.5]),
        [-2.0, -1.0, -3.0],
        [300.0, -40.0, 120.0, 9.0],
        1.0,
        &mut rng,
    );
    compare_with_reference(&scene, &cam, &[0.2, 0.0, 1.0]);
}

#[test]
fn non_finite_and_overflowing_inputs_are_skipped_cleanly() {
    let cam = camera(40, 36);
    let clean = random_scene(50, 3, &cam, 5);
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut dirty = clean.clone();
    let m = [0.0, 0.0, 0.0];
    let q = [1.0, 0.0, 0.0, 0.0];
    dirty.push([f32::NAN, 0.0, 0.0], [-1.0; 3], q, 1.0, &mut rng);
    dirty.push([0.0, f32::INFINITY, 0.0], [-1.0; 3], q, 1.0, &mut rng);
    dirty.push(m, [f32::NAN, 0.0, 0.0], q, 1.0, &mut rng);
    dirty.push(m, [f32::INFINITY; 3], q, 1.0, &mut rng);
    dirty.push(m, [60.0, -1.0, -1.0], q, 1.0, &mut rng); // covariance overflows f32
    dirty.push(m, [-1.0; 3], [f32::NAN, 0.0, 0.0, 1.0], 1.0, &mut rng);
    dirty.push(m, [-1.0; 3], [f32::INFINITY, 0.0, 0.0, 1.0], 1.0, &mut rng);
    dirty.push(m, [-1.0; 3], [f32::MAX, f32::MAX, 0.0, 0.0], 1.0, &mut rng);
    dirty.push(m, [-1.0; 3], q, f32::NAN, &mut rng);
    dirty.push(m, [-1.0; 3], q, f32::INFINITY, &mut rng);
    dirty.push(m, [-1.0; 3], q, 2.0, &mut rng);
    let last = dirty.features.len() - 3;
    dirty.features[last + 1] = f32::NAN;
    let (want, _) = render(&clean.splats(), &cam, &[]).unwrap();
    let (got, state) = render(&dirty.splats(), &cam, &[]).unwrap();
    assert!(got.features.iter().chain(&got.depth).chain(&got.alpha).all(|v| v.is_finite()));
    assert_eq!(got, want, "skipped Gaussians must leave the image exactly as without them");
    assert!(state.intersections() > 0);
}

#[test]
fn bad_arguments_are_errors() {
    let cam = camera(16, 16);
    let scene = random_scene(4, 3, &cam, 1);
    let mut s = scene.splats();
    assert!(matches!(
        render(&s, &cam, &[1.0]),
        Err(RenderError::Background { expected: 3, got: 1 })
    ));
    assert!(matches!(
        render(&s, &cam, &[1.0, f32::NAN, 0.0]),
        Err(RenderError::NonFiniteBackground(_))
    ));
    s.logit_opacity = &scene.logits[..3];
    assert!(matches!(
        render(&s, &cam, &[]),
        Err(RenderError::Length { field: "logit_opacity", .. })
    ));
    let mut bad_cam = cam;
    bad_cam.intrinsics.width = 0;
    assert!(matches!(render(&scene.splats(), &bad_cam, &[]), Err(RenderError::EmptyImage { .. })));
    let mut bad_cam = cam;
    bad_cam.rotation = Quat::from_xyzw(f32::NAN, 0.0, 0.0, 1.0);
    assert!(matches!(render(&scene.splats(), &bad_cam, &[]), Err(RenderError::Camera(_))));
}

#[test]
fn zero_channels_render_depth_and_alpha() {
    let cam = camera(30, 20);
    let scene = random_scene(30, 0, &cam, 4);
    let image = compare_with_reference(&scene, &cam, &[]);
    assert!(image.features.is_empty() && image.alpha.iter().any(|&a| a > 0.1));
}

/// A random scene whose features are the one-hot codes of random ids 0..=`ids` (0: none,
/// an all-zero code), and those ids.
fn one_hot_scene(n: usize, ids: u32, cam: &Camera, seed: u64) -> (Scene, Vec<u32>) {
    let mut scene = random_scene(n, 0, cam, seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1d);
    let id_of: Vec<u32> = (0..n).map(|_| rng.random_range(0..=ids)).collect();
    scene.channels = ids as usize;
    scene.features = id_of
        .iter()
        .flat_map(|&id| (1..=ids).map(move |k| if k == id { 1.0 } else { 0.0 }))
        .collect();
    (scene, id_of)
}

/// Pixels where two id maps differ, as (pixel, a, b), at most 10.
fn id_differences(a: &[u32], b: &[u32]) -> Vec<(usize, u32, u32)> {
    a.iter()
        .zip(b)
        .enumerate()
        .filter(|(_, (x, y))| x != y)
        .map(|(p, (&x, &y))| (p, x, y))
        .take(10)
        .collect()
}

#[test]
fn ids_render_like_one_hot_channels() {
    let cases = [(64, 48, 400, 3), (128, 128, 3000, 40), (37, 29, 150, 1), (96, 80, 2000, 8)];
    for (seed, (w, h, n, k)) in cases.into_iter().enumerate() {
        let cam = camera(w, h);
        let (scene, ids) = one_hot_scene(n, k, &cam, 300 + seed as u64);
        let one_hot = render(&scene.splats(), &cam, &[]).unwrap().0;
        // Same weights summed in the same order, settled pixels only stopped where later
        // Gaussians could not change them: equal, ties included.
        for min_alpha in [0.0, 0.5, 0.9] {
            let want = IdImage::from_one_hot(&one_hot, min_alpha);
            let got = render_ids(&scene.splats(), &ids, &cam, min_alpha).unwrap();
            let what =
                format!("case {seed}, alpha > {min_alpha}: (pixel, ids, one-hot) that differ");
            assert_eq!(id_differences(&got.ids, &want.ids), vec![], "{what}");
            let covered = got.ids.iter().filter(|&&id| id != 0).count();
            assert!(covered * 10 > got.ids.len(), "case {seed}: only {covered} pixels have an id");
        }
    }
    let cam = camera(20, 20);
    let (scene, ids) = one_hot_scene(10, 2, &cam, 1);
    assert!(matches!(
        render_ids(&scene.splats(), &ids[1..], &cam, 0.5),
        Err(RenderError::Length { field: "ids", expected: 10, got: 9 })
    ));
}

/// The wgpu adapter, or `None` (and a note) where there is none; in CI there must be one.
#[cfg(feature = "gpu")]
fn gpu_or_skip(test: &str) -> Option<inssplat_raster::render::GpuRenderer> {
    match inssplat_raster::render::GpuRenderer::new() {
        Ok(gpu) => {
            eprintln!("wgpu adapter: {}", gpu.adapter());
            Some(gpu)
        }
        Err(e) => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "no wgpu adapter in CI ({e}); lavapipe (mesa-vulkan-drivers) must be installed"
            );
            eprintln!("SKIPPED {test}: no wgpu adapter ({e})");
            None
        }
    }
}

/// GPU vs CPU tolerance: the shader uses the GPU's exp and evaluation order, so values agree
/// to float rounding; 1e-4 + 1e-3·|cpu| leaves room for rare flips at the 1/255 cutoff.
#[cfg(feature = "gpu")]
#[test]
fn wgpu_matches_cpu() {
    let Some(gpu) = gpu_or_skip("wgpu_matches_cpu") else { return };
    let cases = [(37, 29, 60, 3), (64, 48, 400, 19), (50, 70, 150, 0), (128, 128, 3000, 8)];
    for (seed, (w, h, n, c)) in cases.into_iter().enumerate() {
        let cam = camera(w, h);
        let scene = random_scene(n, c, &cam, 100 + seed as u64);
        let bg: Vec<f32> = (0..c).map(|i| 0.05 * i as f32).collect();
        let (cpu, _) = render(&scene.splats(), &cam, &bg).unwrap();
        let (got, backend) = render_any(Some(&gpu), &scene.splats(), &cam, &bg).unwrap();
        assert_eq!(backend, Backend::Wgpu);
        let cpu64 = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        assert_close(
            &format!("case {seed} features"),
            &got.features,
            &cpu64(&cpu.features),
            w as usize,
            1e-4,
            1e-3,
        );
        assert_close(
            &format!("case {seed} alpha"),
            &got.alpha,
            &cpu64(&cpu.alpha),
            w as usize,
            1e-4,
            1e-3,
        );
        assert_close(
            &format!("case {seed} depth"),
            &got.depth,
            &cpu64(&cpu.depth),
            w as usize,
            1e-4,
            1e-3,
        );
    }
}

/// The wgpu id path (one-hot channels) against the CPU one: rounding may flip a near tie or
/// an alpha at the threshold, so at most 1% of the pixels may differ.
#[cfg(feature = "gpu")]
#[test]
fn wgpu_ids_match_cpu() {
    let Some(gpu) = gpu_or_skip("wgpu_ids_match_cpu") else { return };
    let cam = camera(128, 96);
    let (scene, ids) = one_hot_scene(3000, 12, &cam, 7);
    let cpu = render_ids(&scene.splats(), &ids, &cam, 0.5).unwrap();
    let (got, backend) = render_ids_any(Some(&gpu), &scene.splats(), &ids, &cam, 0.5).unwrap();
    assert_eq!(backend, Backend::Wgpu);
    let differ = got.ids.iter().zip(&cpu.ids).filter(|(a, b)| a != b).count();
    assert!(differ * 100 <= cpu.ids.len(), "{differ} of {} pixels differ", cpu.ids.len());
}

#[test]
fn render_any_without_gpu_uses_cpu() {
    let cam = camera(20, 20);
    let scene = random_scene(10, 2, &cam, 2);
    let (image, backend) = render_any(None, &scene.splats(), &cam, &[]).unwrap();
    assert_eq!(backend, Backend::Cpu);
    assert_eq!(image, render(&scene.splats(), &cam, &[]).unwrap().0);
    let (scene, ids) = one_hot_scene(10, 2, &cam, 2);
    let (image, backend) = render_ids_any(None, &scene.splats(), &ids, &cam, 0.5).unwrap();
    assert_eq!(backend, Backend::Cpu);
    assert_eq!(image, render_ids(&scene.splats(), &ids, &cam, 0.5).unwrap());
}
