//! Rasterizer benchmark: `cargo bench -p inssplat-raster --bench render`.
//!
//! Forward and backward time (median of several runs) of the CPU tile rasterizer for 30k and
//! 130k Gaussians at 128² and 448² with 3 and 24 channels, the wgpu forward where an adapter
//! exists, and the serving case: 8 views × 19 channels of a 30k-Gaussian scene at 128² (target
//! ≤ 50 ms). Each time is also given as a ratio to a memory-bandwidth bound: the bytes a pass
//! must move at least (Gaussian parameters and features read, image planes written, the
//! per-tile index lists written and read; the backward also reads the output gradients and
//! writes the parameter gradients) divided by the copy bandwidth measured at start-up. Last,
//! what filling a new view's uncovered pixels costs beside its render.

use std::time::{Duration, Instant};

use glam::Vec3;
use inssplat_proto::{Camera, Intrinsics};
use inssplat_raster::fill::{fill_colour, nearest_covered};
use inssplat_raster::masks::MASK_ALPHA;
use inssplat_raster::render::{GpuRenderer, render, render_any, render_backward};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[path = "../tests/support/mod.rs"]
mod support;
use support::Scene;

/// A camera inside the room, turned by `angle` about the vertical, looking across it.
fn camera(size: u32, angle: f32) -> Camera {
    let k = Intrinsics::from_fov_y(size, size, 1.0);
    let eye = Vec3::new(1.7 * angle.sin(), -0.2, -1.7 * angle.cos());
    Camera::look_at(k, eye, Vec3::new(0.0, -0.4, 0.0), Vec3::Y)
}

/// Surfel Gaussians on a surface point with normal `normal`, `spacing` apart.
fn surfel(rng: &mut ChaCha8Rng, s: &mut Scene, p: Vec3, normal: Vec3, spacing: f32) {
    let q = glam::Quat::from_rotation_arc(Vec3::Z, normal.normalize());
    let size = (0.6 * spacing * rng.random_range(0.8..1.25f32)).ln();
    s.means.push(p.to_array());
    s.log_scales.push([size, size, size - 1.6]);
    s.rotations.push([q.w, q.x, q.y, q.z]);
    s.logits.push(rng.random_range(1.0..5.0));
    s.features.extend((0..s.channels).map(|_| rng.random_range(0.0..1.0f32)));
}

/// What the voxelizer makes of an indoor scene: flat Gaussians covering the walls, floor and
/// ceiling of a 4 × 3 × 4 room (60%) and six spheres standing in it (40%), each about as
/// wide as the spacing between neighbours (≈ 2 px at 128² for 30k Gaussians).
fn scene(n: usize, channels: usize) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(n as u64);
    let mut s = Scene {
        means: vec![],
        log_scales: vec![],
        rotations: vec![],
        logits: vec![],
        features: vec![],
        channels,
    };
    let half = Vec3::new(2.0, 1.5, 2.0);
    let walls = n * 6 / 10;
    let area = 8.0 * (half.x * half.y + half.y * half.z + half.z * half.x);
    let spacing = (area / walls as f32).sqrt();
    while s.means.len() < walls {
        let axis = rng.random_range(0..3usize);
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let mut p = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ) * half;
        // Faces of a larger area are picked proportionally more often.
        let face_area = match axis {
            0 => half.y * half.z,
            1 => half.x * half.z,
            _ => half.x * half.y,
        };
        if rng.random_range(0.0..half.x * half.z) > face_area {
            continue;
        }
        p[axis] = sign * half[axis];
        let mut normal = Vec3::ZERO;
        normal[axis] = -sign;
        surfel(&mut rng, &mut s, p, normal, spacing);
    }
    let spheres: Vec<(Vec3, f32)> = (0..6)
        .map(|i| {
            let a = i as f32 * 1.05;
            (Vec3::new(0.9 * a.cos(), -1.0, 0.9 * a.sin()), 0.3 + 0.05 * i as f32)
        })
        .collect();
    let sphere_area: f32 = spheres.iter().map(|(_, r)| 4.0 * std::f32::consts::PI * r * r).sum();
    let spacing = (sphere_area / (n - walls) as f32).sqrt();
    while s.means.len() < n {
        let (c, r) = spheres[rng.random_range(0..spheres.len())];
        let d = Vec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if d.length() > 1.0 || d.length() < 0.1 {
            continue;
        }
        surfel(&mut rng, &mut s, c + d.normalize() * r, d, spacing);
    }
    s
}

fn median(mut runs: Vec<Duration>) -> Duration {
    runs.sort();
    runs[runs.len() / 2]
}

/// CPU time (user + system, all threads) of this process so far, from /proc/self/stat.
fn cpu_time() -> Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesized command name; utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let ticks: u64 =
        rest.split_whitespace().skip(11).take(2).filter_map(|v| v.parse::<u64>().ok()).sum();
    Duration::from_millis(ticks * 10) // USER_HZ = 100 on Linux
}

/// Median wall time of `runs` calls after a warm-up, and the mean CPU time per call.
fn time<T>(runs: usize, mut f: impl FnMut() -> T) -> (Duration, Duration) {
    f();
    let cpu = cpu_time();
    let wall = median(
        (0..runs)
            .map(|_| {
                let start = Instant::now();
                std::hint::black_box(f());
                start.elapsed()
            })
            .collect(),
    );
    (wall, (cpu_time() - cpu) / runs as u32)
}

/// Copy bandwidth in bytes/s (read + write counted) over a buffer far larger than the caches.
fn bandwidth() -> f64 {
    let src = vec![1.0f32; 64 << 20];
    let mut dst = vec![0.0f32; 64 << 20];
    let (t, _) = time(5, || {
        dst.copy_from_slice(&src);
        dst[17]
    });
    2.0 * (src.len() * 4) as f64 / t.as_secs_f64()
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn main() {
    let bw = bandwidth();
    let gpu = GpuRenderer::new().ok();
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "threads: {}, copy bandwidth: {:.1} GB/s, load average: {}",
        rayon::current_num_threads(),
        bw / 1e9,
        load.trim()
    );
    println!(
        "times: median wall ms of 9 runs (CPU ms per run, all threads, in brackets; 10 ms resolution)"
    );
    println!("wgpu: {}", gpu.as_ref().map_or("no adapter".into(), |g| g.adapter()));
    println!();
    println!(
        "| Gaussians | size | channels | isects | fwd ms (cpu) | fwd / bw bound | bwd ms (cpu) | bwd / bw bound | wgpu fwd ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for n in [30_000, 130_000] {
        for size in [128u32, 448] {
            for channels in [3usize, 24] {
                let s = scene(n, channels);
                let cam = camera(size, 0.3);
                let splats = s.splats();
                let pixels = (size * size) as usize;
                let (image, state) = render(&splats, &cam, &[]).unwrap();
                let isects = state.intersections();
                let (fwd, fwd_cpu) = time(9, || render(&splats, &cam, &[]).unwrap());
                let d_features = vec![1e-3f32; image.features.len()];
                let d_other = vec![1e-3f32; pixels];
                let (bwd, bwd_cpu) = time(9, || {
                    render_backward(&splats, &cam, &state, &d_features, &d_other, &d_other)
                });
                let params = n * (11 + channels) * 4;
                let planes = pixels * (channels + 2) * 4;
                let fwd_bytes = params + planes + 2 * isects * 4;
                let bwd_bytes = 2 * params + planes + 2 * isects * 4;
                let wgpu = match &gpu {
                    Some(g) => format!(
                        "{:.1}",
                        ms(time(3, || render_any(Some(g), &splats, &cam, &[]).unwrap()).0)
                    ),
                    None => "-".into(),
                };
                println!(
                    "| {n} | {size}² | {channels} | {isects} | {:.1} ({:.0}) | {:.0}× | {:.1} ({:.0}) | {:.0}× | {wgpu} |",
                    ms(fwd),
                    ms(fwd_cpu),
                    fwd.as_secs_f64() / (fwd_bytes as f64 / bw),
                    ms(bwd),
                    ms(bwd_cpu),
                    bwd.as_secs_f64() / (bwd_bytes as f64 / bw),
                );
            }
        }
    }

    println!();
    println!("serving case: 8 views × 19 channels, 30k Gaussians, 128² (target ≤ 50 ms)");
    let s = scene(30_000, 19);
    let cams: Vec<Camera> = (0..8).map(|i| camera(128, i as f32 * 0.4)).collect();
    let (wall, cpu) =
        time(7, || cams.iter().map(|c| render(&s.splats(), c, &[]).unwrap().0).collect::<Vec<_>>());
    println!("cpu rasterizer: {:.1} ms wall ({:.0} ms CPU)", ms(wall), ms(cpu));
    if let Some(g) = &gpu {
        let (t, _) = time(5, || {
            cams.iter()
                .map(|c| render_any(Some(g), &s.splats(), c, &[]).unwrap())
                .collect::<Vec<_>>()
        });
        println!("wgpu ({}): {:.1} ms wall", g.adapter(), ms(t));
    }

    println!();
    println!(
        "a new view's fill (push-pull colours, nearest covered pixel for ids), against its 3-channel forward, 30k Gaussians"
    );
    println!("| size | uncovered | forward ms | fill ms | fill / forward |");
    println!("|---|---|---|---|---|");
    let s = scene(30_000, 3);
    for size in [128u32, 448] {
        // A view turned across the room; the fill's work hardly depends on how much of it is
        // open (the whole pyramid, and one pass over the pixels for the ids).
        let cam = camera(size, 2.4);
        let (image, _) = render(&s.splats(), &cam, &[]).unwrap();
        let (w, h) = (size as usize, size as usize);
        let covered: Vec<bool> = image.alpha.iter().map(|&a| a > MASK_ALPHA).collect();
        let (fwd, _) = time(9, || render(&s.splats(), &cam, &[]).unwrap());
        let (fill, _) = time(9, || {
            (
                fill_colour(&image.features, &image.alpha, w, h, MASK_ALPHA),
                nearest_covered(&covered, w, h),
            )
        });
        let open = covered.iter().filter(|&&c| !c).count() as f64 / covered.len() as f64;
        println!(
            "| {size}² | {:.0}% | {:.2} | {:.2} | {:.2} |",
            100.0 * open,
            ms(fwd),
            ms(fill),
            fill.as_secs_f64() / fwd.as_secs_f64()
        );
    }
}
