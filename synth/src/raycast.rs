//! The CPU ray caster: closest hits against the room shell (analytic, the camera is always
//! inside) and the placed objects (a world-space bounds test, then the object's own BVH with
//! the ray moved into object space: rotation and uniform scale leave `t` unchanged), shadow
//! rays for the point lights, and Lambert + ambient shading. It renders one frame into
//! linear RGB (anti-aliased by several rays a pixel if asked), depth along the camera axis
//! and instance ids; pixels are independent, so the result does not depend on how rayon
//! splits the rows.

use glam::{Quat, Vec3};
use inssplat_proto::camera::Camera;
use rayon::prelude::*;

use super::room::{Placed, Room, Surface};

/// Instance ids of the room shell, indexed like [`Surface::ALL`] (0 = background).
pub type ShellIds = [u16; 6];

/// Everything a ray can meet.
pub struct World<'a> {
    pub room: &'a Room,
    pub objects: Vec<Object<'a>>,
    pub shell_ids: ShellIds,
}

/// A placed object with what the inner loop needs precomputed.
pub struct Object<'a> {
    placed: &'a Placed,
    inv_rotation: Quat,
    rotation: Quat,
    inv_scale: f32,
    lo: Vec3,
    hi: Vec3,
    pub id: u16,
}

/// What a primary ray saw.
#[derive(Debug, Clone, Copy)]
struct Hit {
    t: f32,
    point: Vec3,
    normal: Vec3,
    albedo: Vec3,
    id: u16,
}

/// One rendered frame.
pub struct FrameBuffers {
    /// Linear RGB radiance, row-major.
    pub radiance: Vec<Vec3>,
    /// Depth along the camera z axis, metres (0 = no hit, which cannot happen inside a room).
    pub depth: Vec<f32>,
    pub ids: Vec<u16>,
}

impl<'a> World<'a> {
    /// `ids[i]` is the instance id of `objects[i]`.
    pub fn new(room: &'a Room, objects: &'a [Placed], ids: &[u16], shell_ids: ShellIds) -> Self {
        let objects = objects
            .iter()
            .zip(ids)
            .map(|(p, &id)| {
                let (lo, hi) = p.bounds();
                Object {
                    placed: p,
                    rotation: p.rotation(),
                    inv_rotation: p.rotation().inverse(),
                    inv_scale: 1.0 / p.scale,
                    lo: lo - Vec3::splat(1e-4),
                    hi: hi + Vec3::splat(1e-4),
                    id,
                }
            })
            .collect();
        World { room, objects, shell_ids }
    }

    /// Entry distance of `o + t·d` into an object's world bounds, if it meets them before `tmax`.
    fn slab(o: Vec3, inv_d: Vec3, lo: Vec3, hi: Vec3, tmax: f32) -> Option<f32> {
        let t0 = (lo - o) * inv_d;
        let t1 = (hi - o) * inv_d;
        let near = t0.min(t1).max_element().max(0.0);
        let far = t0.max(t1).min_element().min(tmax);
        (near <= far).then_some(near)
    }

    fn shell(&self, o: Vec3, d: Vec3) -> (f32, Surface) {
        let s = self.room.size;
        let mut best = (f32::INFINITY, Surface::Floor);
        let axes = [
            (d.x, o.x, 0.0, s.x, Surface::WallX0, Surface::WallX1),
            (d.y, o.y, 0.0, s.y, Surface::Floor, Surface::Ceiling),
            (d.z, o.z, 0.0, s.z, Surface::WallZ0, Surface::WallZ1),
        ];
        for (dv, ov, lo, hi, neg, pos) in axes {
            let (t, surf) = if dv > 0.0 {
                ((hi - ov) / dv, pos)
            } else if dv < 0.0 {
                ((lo - ov) / dv, neg)
            } else {
                continue;
            };
            if t < best.0 {
                best = (t, surf);
            }
        }
        best
    }

    fn trace(&self, o: Vec3, d: Vec3) -> Hit {
        let (t_shell, surface) = self.shell(o, d);
        let idx = Surface::ALL.iter().position(|&s| s == surface).expect("surface");
        let point = o + d * t_shell;
        let normal = match surface {
            Surface::Floor => Vec3::Y,
            Surface::Ceiling => Vec3::NEG_Y,
            Surface::WallX0 => Vec3::X,
            Surface::WallX1 => Vec3::NEG_X,
            Surface::WallZ0 => Vec3::Z,
            Surface::WallZ1 => Vec3::NEG_Z,
        };
        let albedo = self.room.surfaces[idx].albedo(Room::surface_uv(surface, point));
        let mut best = Hit { t: t_shell, point, normal, albedo, id: self.shell_ids[idx] };
        let inv_d = d.recip();
        for ob in &self.objects {
            let Some(enter) = Self::slab(o, inv_d, ob.lo, ob.hi, best.t) else { continue };
            if enter > best.t {
                continue;
            }
            let lo = ob.inv_rotation * (o - ob.placed.position) * ob.inv_scale;
            let ld = ob.inv_rotation * d * ob.inv_scale;
            if let Some(h) = ob.placed.model.mesh.closest(lo, ld, 0.0, best.t) {
                let mut n = ob.rotation * h.normal;
                if n.dot(d) > 0.0 {
                    n = -n;
                }
                let material = &ob.placed.model.mesh.materials[h.material as usize];
                best = Hit {
                    t: h.t,
                    point: o + d * h.t,
                    normal: n,
                    albedo: material.shade(h.uv),
                    id: ob.id,
                };
            }
        }
        best
    }

    /// Whether something blocks the segment from `p` to `p + d` (t in (0, 1)).
    fn occluded(&self, p: Vec3, d: Vec3) -> bool {
        let inv_d = d.recip();
        self.objects.iter().any(|ob| {
            Self::slab(p, inv_d, ob.lo, ob.hi, 1.0).is_some() && {
                let lo = ob.inv_rotation * (p - ob.placed.position) * ob.inv_scale;
                let ld = ob.inv_rotation * d * ob.inv_scale;
                ob.placed.model.mesh.occludes(lo, ld, 1e-4, 1.0 - 1e-4)
            }
        })
    }

    fn shade(&self, h: &Hit) -> Vec3 {
        // Hemispherical ambient: a little brighter from above.
        let mut light = self.room.ambient * (0.75 + 0.25 * h.normal.y);
        let p = h.point + h.normal * 2e-3;
        for l in &self.room.lights {
            let to = l.position - p;
            let dist2 = to.length_squared();
            let cos = h.normal.dot(to) / dist2.sqrt();
            if cos <= 0.0 || self.occluded(p, to) {
                continue;
            }
            light += l.color * cos / (1.0 + dist2);
        }
        h.albedo * light
    }

    /// Renders one view. Each pixel's colour is the mean of `samples`² rays on a stratified
    /// grid inside it (1: the ray through its centre), as a camera's pixel integrates the
    /// light over its area; its depth and instance id are the centre ray's, so the labels stay
    /// exact whatever the colour's anti-aliasing.
    pub fn render(&self, cam: &Camera, samples: u32) -> FrameBuffers {
        let k = cam.intrinsics;
        let (w, h) = (k.width as usize, k.height as usize);
        let origin = cam.center();
        let to_world = cam.rotation.inverse();
        // Camera-space direction with z = 1 through (u, v), so the hit distance is the depth.
        let ray = |u: f32, v: f32| to_world * Vec3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
        let n = samples.max(1);
        let offsets: Vec<f32> = (0..n).map(|i| (i as f32 + 0.5) / n as f32).collect();
        let rows: Vec<Vec<(Vec3, f32, u16)>> = (0..h)
            .into_par_iter()
            .map(|y| {
                (0..w)
                    .map(|x| {
                        let centre = self.trace(origin, ray(x as f32 + 0.5, y as f32 + 0.5));
                        let colour = if n == 1 {
                            self.shade(&centre)
                        } else {
                            let mut sum = Vec3::ZERO;
                            for &dy in &offsets {
                                for &dx in &offsets {
                                    sum += self.shade(
                                        &self.trace(origin, ray(x as f32 + dx, y as f32 + dy)),
                                    );
                                }
                            }
                            sum / (n * n) as f32
                        };
                        (colour, centre.t, centre.id)
                    })
                    .collect()
            })
            .collect();
        let mut out = FrameBuffers {
            radiance: Vec::with_capacity(w * h),
            depth: Vec::with_capacity(w * h),
            ids: Vec::with_capacity(w * h),
        };
        for (c, t, id) in rows.into_iter().flatten() {
            out.radiance.push(c);
            out.depth.push(t);
            out.ids.push(id);
        }
        out
    }

    /// Distance along `d` (unit length) to the first surface seen from `o`.
    pub fn probe(&self, o: Vec3, d: Vec3) -> f32 {
        self.trace(o, d).t
    }

    /// Whether a person standing at `p` (any height) would be within `margin` of an object's
    /// floor plan; flat things on the floor (rugs) do not count.
    pub fn near_object(&self, p: Vec3, margin: f32) -> bool {
        self.objects.iter().any(|o| {
            o.hi.y - o.lo.y > 0.05
                && p.x >= o.lo.x - margin
                && p.x <= o.hi.x + margin
                && p.z >= o.lo.z - margin
                && p.z <= o.hi.z + margin
        })
    }

    /// The centres of the objects' bounds, with their sizes, for camera aiming.
    pub fn object_centres(&self) -> Vec<(Vec3, f32)> {
        self.objects.iter().map(|o| (0.5 * (o.lo + o.hi), (o.hi - o.lo).length())).collect()
    }
}

#[cfg(test)]
mod tests {
    use inssplat_proto::camera::Intrinsics;
    use rand::SeedableRng;

    use super::super::layout::{Source, furnish};
    use super::super::{Furniture, Reserved, Split, SynthConfig};
    use super::*;

    /// A furnished room (primitives) and a camera looking across it at 24².
    fn view() -> (Room, Vec<Placed>, Camera) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let room = Room::random(&mut rng, 1.0);
        let cfg = SynthConfig::new(Split::Train, Furniture::Primitives);
        let src =
            Source { catalog: None, reserved: Reserved::Exclude, mesh_share: 0.0, contrast: 1.0 };
        let objects = furnish(&room, &src, &cfg, &mut rng).objects;
        let eye = Vec3::new(0.3 * room.size.x, 1.5, 0.2 * room.size.z);
        let target = Vec3::new(0.7 * room.size.x, 0.5, 0.8 * room.size.z);
        (room, objects, Camera::look_at(Intrinsics::from_fov_y(24, 24, 1.1), eye, target, Vec3::Y))
    }

    #[test]
    fn antialiased_colour_is_the_mean_of_the_finer_grid_and_labels_stay_the_centres() {
        let (room, objects, cam) = view();
        let ids: Vec<u16> = (1..=objects.len() as u16).collect();
        let world = World::new(&room, &objects, &ids, [0; 6]);
        let plain = world.render(&cam, 1);
        let smooth = world.render(&cam, 2);
        let fine_cam = Camera { intrinsics: Intrinsics::from_fov_y(48, 48, 1.1), ..cam };
        let fine = world.render(&fine_cam, 1);
        let mut edges = 0;
        for y in 0..24 {
            for x in 0..24 {
                let i = y * 24 + x;
                let block = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .map(|(dx, dy)| fine.radiance[(2 * y + dy) * 48 + 2 * x + dx]);
                let mean = block.iter().copied().sum::<Vec3>() / 4.0;
                assert!(
                    (smooth.radiance[i] - mean).abs().max_element() < 1e-5,
                    "pixel ({x}, {y}): {} against {mean}",
                    smooth.radiance[i]
                );
                assert_eq!(
                    (smooth.depth[i], smooth.ids[i]),
                    (plain.depth[i], plain.ids[i]),
                    "pixel ({x}, {y})"
                );
                edges += usize::from(
                    (smooth.radiance[i] - plain.radiance[i]).abs().max_element() > 1e-3,
                );
            }
        }
        assert!(
            objects.len() >= 3 && edges > 20,
            "{} objects, {edges} pixels changed by anti-aliasing",
            objects.len()
        );
    }
}
