//! Camera paths a person with a phone would walk: an arc around the furniture, a walk across
//! the room, or a sideways sweep along a wall, at eye height with a little bob, hand shake
//! and roll, aimed at the objects. Frames are spaced unevenly along the path; the `overlap`
//! knob shortens the path (1 = nearly the same view every frame, 0 = the whole room). Every
//! camera stays inside the room and out of the furniture.

use std::f32::consts::{PI, TAU};

use glam::{Quat, Vec3};
use inssplat_proto::camera::{Camera, Intrinsics};
use rand::Rng;

use super::raycast::World;

const WALL_CLEARANCE: f32 = 0.3;
const OBJECT_CLEARANCE: f32 = 0.15;
/// The surface at the image centre must be at least this far: no views of a cabinet's back
/// from a hand's width away.
const MIN_VIEW_DISTANCE: f32 = 0.7;

/// `n` cameras along one random path.
pub fn cameras(
    world: &World,
    n: usize,
    overlap: f32,
    k: Intrinsics,
    rng: &mut impl Rng,
) -> Vec<Camera> {
    let size = world.room.size;
    let targets = world.object_centres();
    for _ in 0..40 {
        let path = random_path(world, &targets, overlap, rng);
        let cams = sample(&path, n, k, rng);
        if valid(world, &cams) {
            return cams;
        }
    }
    // Crowded room: stand at a free spot and turn to look around.
    for _ in 0..40 {
        let eye = Vec3::new(
            rng.random_range(WALL_CLEARANCE..size.x - WALL_CLEARANCE),
            rng.random_range(1.2..1.7),
            rng.random_range(WALL_CLEARANCE..size.z - WALL_CLEARANCE),
        );
        if world.near_object(eye, OBJECT_CLEARANCE) {
            continue;
        }
        let step = Vec3::new(rng.random_range(-0.1..0.1), 0.0, rng.random_range(-0.1..0.1));
        let look = (0..3).map(|_| look_around(eye, &targets, rng)).collect();
        let cams =
            sample(&Path { kind: Kind::Line { from: eye, to: eye + step }, look }, n, k, rng);
        if valid(world, &cams) {
            return cams;
        }
    }
    // No free floor at all: a slow arc high under the ceiling, above the furniture.
    let mut path = Path::orbit(
        Vec3::new(0.5 * size.x, 0.5, 0.5 * size.z),
        0.25 * size.x.min(size.z),
        rng.random_range(0.0..TAU),
        PI / 3.0,
        size.y - 0.3,
    );
    path.look = vec![Vec3::new(0.5 * size.x, 0.4, 0.5 * size.z)];
    sample(&path, n, k, rng)
}

/// Inside the room, clear of furniture, not looking straight down, not facing a surface
/// at arm's length.
fn valid(world: &World, cams: &[Camera]) -> bool {
    let size = world.room.size;
    cams.iter().all(|c| {
        let e = c.center();
        let forward = c.rotation.inverse() * Vec3::Z;
        e.x > WALL_CLEARANCE
            && e.z > WALL_CLEARANCE
            && e.x < size.x - WALL_CLEARANCE
            && e.z < size.z - WALL_CLEARANCE
            && e.y < size.y - 0.15
            && !world.near_object(e, OBJECT_CLEARANCE)
            && forward.y > -0.9
            && world.probe(e, forward) > MIN_VIEW_DISTANCE
    })
}

/// A path: eye position over s ∈ [0, 1] and the points it looks at (interpolated over s).
struct Path {
    kind: Kind,
    look: Vec<Vec3>,
}

enum Kind {
    Orbit { centre: Vec3, radius: f32, start: f32, span: f32, height: f32 },
    Line { from: Vec3, to: Vec3 },
}

impl Path {
    fn orbit(centre: Vec3, radius: f32, start: f32, span: f32, height: f32) -> Path {
        Path { kind: Kind::Orbit { centre, radius, start, span, height }, look: vec![centre] }
    }

    fn eye(&self, s: f32) -> Vec3 {
        match self.kind {
            Kind::Orbit { centre, radius, start, span, height } => {
                let a = start + span * s;
                Vec3::new(centre.x + radius * a.cos(), height, centre.z + radius * a.sin())
            }
            Kind::Line { from, to } => from.lerp(to, s),
        }
    }

    fn target(&self, s: f32) -> Vec3 {
        let n = self.look.len();
        if n == 1 {
            return self.look[0];
        }
        let x = s.clamp(0.0, 1.0) * (n - 1) as f32;
        let i = (x.floor() as usize).min(n - 2);
        let f = x - i as f32;
        let f = f * f * (3.0 - 2.0 * f);
        self.look[i].lerp(self.look[i + 1], f)
    }
}

fn random_path(world: &World, targets: &[(Vec3, f32)], overlap: f32, rng: &mut impl Rng) -> Path {
    let size = world.room.size;
    let inner = |p: Vec3| {
        Vec3::new(
            p.x.clamp(WALL_CLEARANCE + 0.05, size.x - WALL_CLEARANCE - 0.05),
            p.y,
            p.z.clamp(WALL_CLEARANCE + 0.05, size.z - WALL_CLEARANCE - 0.05),
        )
    };
    let mut focus: Vec3 = if targets.is_empty() {
        Vec3::new(0.5 * size.x, 0.5, 0.5 * size.z)
    } else {
        targets.iter().map(|t| t.0).sum::<Vec3>() / targets.len() as f32
    };
    focus.y = rng.random_range(0.35..0.9);
    let height = rng.random_range(1.2..1.7);
    let reach = 1.0 - overlap.clamp(0.0, 1.0);
    let pick = |rng: &mut dyn rand::RngCore| -> Vec3 {
        if targets.is_empty() {
            return focus;
        }
        let (c, _) = targets[rng.random_range(0..targets.len())];
        Vec3::new(c.x, c.y.min(1.2), c.z)
    };
    match rng.random_range(0..3) {
        0 => {
            let max_r = (0.5 * size.x.min(size.z) - WALL_CLEARANCE).max(0.3);
            let centre = inner(focus);
            let radius = rng.random_range(0.5..1.0) * max_r;
            let span = (0.4 + 4.6 * reach) * rng.random_range(0.6..1.0);
            let start = rng.random_range(0.0..TAU);
            let mut p = Path::orbit(centre, radius, start, span.min(TAU), height);
            p.look = vec![centre.with_y(focus.y)];
            p
        }
        1 => {
            // A walk across the room, looking at a few objects in turn.
            let a = inner(Vec3::new(
                rng.random_range(0.0..size.x),
                height,
                rng.random_range(0.0..size.z),
            ));
            let b = inner(Vec3::new(size.x - a.x, height, size.z - a.z));
            let len = (0.15 + 0.85 * reach) * rng.random_range(0.7..1.0);
            let mid = a.lerp(b, rng.random_range(0.0..1.0 - len));
            let to = mid + (b - a) * len;
            let n_look = rng.random_range(2..=3);
            let look = (0..n_look).map(|_| pick(rng)).collect();
            Path { kind: Kind::Line { from: mid, to }, look }
        }
        _ => {
            // A sideways sweep along a wall, looking across the room.
            let along_x = rng.random_bool(0.5);
            let near = rng.random_range(0.45..0.9);
            let (from, to) = if along_x {
                let z = if rng.random_bool(0.5) { near } else { size.z - near };
                (Vec3::new(0.0, height, z), Vec3::new(size.x, height, z))
            } else {
                let x = if rng.random_bool(0.5) { near } else { size.x - near };
                (Vec3::new(x, height, 0.0), Vec3::new(x, height, size.z))
            };
            let (from, to) = (inner(from), inner(to));
            let len = (0.2 + 0.8 * reach) * rng.random_range(0.6..1.0);
            let start = from.lerp(to, rng.random_range(0.0..1.0 - len));
            let end = start + (to - from) * len;
            let look = vec![pick(rng), focus, pick(rng)];
            Path { kind: Kind::Line { from: start, to: end }, look }
        }
    }
}

/// A point to look at from `eye`: an object, or the room around when there is none.
fn look_around(eye: Vec3, targets: &[(Vec3, f32)], rng: &mut impl Rng) -> Vec3 {
    if targets.is_empty() {
        let a = rng.random_range(0.0..TAU);
        return eye + Vec3::new(a.cos(), -0.5, a.sin());
    }
    let (c, _) = targets[rng.random_range(0..targets.len())];
    c.with_y(c.y.min(1.2))
}

/// Moves `target` away from `eye` horizontally until the camera looks down by at most
/// `MAX_PITCH`: people hold phones fairly level.
fn level(eye: Vec3, target: Vec3, rng: &mut impl Rng) -> Vec3 {
    const MAX_PITCH: f32 = 0.65;
    let drop = (eye.y - target.y).max(0.0);
    let flat = Vec3::new(target.x - eye.x, 0.0, target.z - eye.z);
    let need = drop / MAX_PITCH.tan();
    if flat.length() >= need {
        return target;
    }
    let dir = flat.try_normalize().unwrap_or_else(|| {
        let a = rng.random_range(0.0..TAU);
        Vec3::new(a.cos(), 0.0, a.sin())
    });
    Vec3::new(eye.x, target.y, eye.z) + dir * need
}

/// Cameras at uneven steps along `path`, with bob, shake and roll.
fn sample(path: &Path, n: usize, k: Intrinsics, rng: &mut impl Rng) -> Vec<Camera> {
    let steps: Vec<f32> = (0..n).map(|_| rng.random_range(0.4..1.6)).collect();
    let total: f32 = steps.iter().sum::<f32>() - steps[0];
    let mut s = 0.0;
    let bob_phase = rng.random_range(0.0..TAU);
    (0..n)
        .map(|i| {
            if i > 0 {
                s += steps[i] / total.max(1e-6);
            }
            let shake = Vec3::new(
                rng.random_range(-0.03..0.03),
                rng.random_range(-0.03..0.03),
                rng.random_range(-0.03..0.03),
            );
            let eye = path.eye(s) + Vec3::Y * 0.04 * (bob_phase + 9.0 * s).sin() + shake;
            let target = path.target(s)
                + Vec3::new(
                    rng.random_range(-0.15..0.15),
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.15..0.15),
                );
            let target = level(eye, target, rng);
            let forward = (target - eye).normalize();
            let roll = rng.random_range(-0.05..0.05);
            let up = Quat::from_axis_angle(forward, roll) * Vec3::Y;
            Camera::look_at(k, eye, target, up)
        })
        .collect()
}
