//! The room shell and what fills it: an axis-aligned box (floor at y = 0, x ∈ [0, W],
//! z ∈ [0, D], ceiling at y = H) with a procedural pattern per surface, 1–3 point lights under
//! the ceiling, and placed objects (a model, a yaw about +y, a uniform scale and a base
//! position). Footprints are oriented rectangles on the floor; [`Footprint::overlaps`] is the
//! separating-axis test the layout uses to keep furniture apart.

use glam::{Quat, Vec2, Vec3};
use rand::Rng;
use rand::seq::IndexedRandom;

use super::furniture::Model;
use super::texture::{Pattern, PatternKind, jitter_colour, srgb_to_linear};

/// Surfaces of the room shell, in the order of [`Room::surfaces`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    Floor,
    Ceiling,
    /// Walls at x = 0, x = W, z = 0, z = D.
    WallX0,
    WallX1,
    WallZ0,
    WallZ1,
}

impl Surface {
    pub const ALL: [Surface; 6] = [
        Surface::Floor,
        Surface::Ceiling,
        Surface::WallX0,
        Surface::WallX1,
        Surface::WallZ0,
        Surface::WallZ1,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Surface::Floor => "floor",
            Surface::Ceiling => "ceiling",
            _ => "wall",
        }
    }
}

/// A point light.
#[derive(Debug, Clone, Copy)]
pub struct Light {
    pub position: Vec3,
    /// Linear RGB intensity (radiance scale at 1 m).
    pub color: Vec3,
}

#[derive(Debug, Clone)]
pub struct Room {
    /// (W, H, D) in metres.
    pub size: Vec3,
    /// Pattern per surface, indexed like [`Surface::ALL`].
    pub surfaces: [Pattern; 6],
    pub lights: Vec<Light>,
    pub ambient: Vec3,
}

impl Room {
    pub fn random(rng: &mut impl Rng, contrast: f32) -> Room {
        let size = Vec3::new(
            rng.random_range(3.0..6.5),
            rng.random_range(2.4..3.1),
            rng.random_range(3.0..6.5),
        );
        let s =
            |r: u8, g: u8, b: u8| srgb_to_linear(Vec3::new(r as f32, g as f32, b as f32) / 255.0);
        let floor_kind = *[
            PatternKind::WoodPlanks,
            PatternKind::WoodPlanks,
            PatternKind::Tiles,
            PatternKind::Carpet,
            PatternKind::Noise,
        ]
        .choose(rng)
        .expect("kinds");
        let floor_base = match floor_kind {
            PatternKind::WoodPlanks => {
                *[s(200, 160, 115), s(150, 105, 70), s(110, 75, 50), s(225, 205, 175)]
                    .choose(rng)
                    .expect("c")
            }
            PatternKind::Tiles => {
                *[s(220, 220, 215), s(180, 170, 160), s(90, 90, 95), s(200, 185, 160)]
                    .choose(rng)
                    .expect("c")
            }
            _ => Vec3::new(
                rng.random_range(0.05..0.5),
                rng.random_range(0.05..0.45),
                rng.random_range(0.05..0.45),
            ),
        };
        let floor_base = jitter_colour(rng, floor_base, 0.1);
        let floor = Pattern::random(rng, floor_kind, floor_base, contrast);
        let wall_base = if rng.random_bool(0.6) {
            jitter_colour(rng, s(235, 230, 220), 0.06)
        } else {
            Vec3::new(
                rng.random_range(0.15..0.8),
                rng.random_range(0.15..0.8),
                rng.random_range(0.15..0.8),
            )
        };
        let wall_kind =
            *[PatternKind::Plaster, PatternKind::Plaster, PatternKind::Stripes, PatternKind::Noise]
                .choose(rng)
                .expect("k");
        let wall = Pattern::random(rng, wall_kind, wall_base, contrast);
        let accent = if rng.random_bool(0.3) {
            let c = Vec3::new(
                rng.random_range(0.1..0.7),
                rng.random_range(0.1..0.7),
                rng.random_range(0.1..0.7),
            );
            Pattern::random(rng, PatternKind::Plaster, c, contrast)
        } else {
            wall
        };
        let ceiling_base = jitter_colour(rng, s(245, 245, 240), 0.03);
        let ceiling = Pattern::random(rng, PatternKind::Plaster, ceiling_base, contrast * 0.5);
        let accent_wall = rng.random_range(0..4);
        let walls: [Pattern; 4] =
            std::array::from_fn(|i| if i == accent_wall { accent } else { wall });
        let n_lights = rng.random_range(1..=3);
        let warmth = rng.random_range(0.0..1.0f32);
        let tint = Vec3::new(1.0, 0.92 + 0.06 * (1.0 - warmth), 0.78 + 0.2 * (1.0 - warmth));
        let power = size.x * size.z * rng.random_range(0.35..0.6) / n_lights as f32;
        let lights = (0..n_lights)
            .map(|_| Light {
                position: Vec3::new(
                    rng.random_range(0.2..0.8) * size.x,
                    size.y - rng.random_range(0.2..0.5),
                    rng.random_range(0.2..0.8) * size.z,
                ),
                color: tint * power * rng.random_range(0.7..1.3),
            })
            .collect();
        Room {
            size,
            surfaces: [floor, ceiling, walls[0], walls[1], walls[2], walls[3]],
            lights,
            ambient: tint * rng.random_range(0.12..0.25),
        }
    }

    /// Surface coordinate (metres) of a point on `surface`.
    pub fn surface_uv(surface: Surface, p: Vec3) -> Vec2 {
        match surface {
            Surface::Floor | Surface::Ceiling => Vec2::new(p.x, p.z),
            Surface::WallX0 | Surface::WallX1 => Vec2::new(p.z, p.y),
            Surface::WallZ0 | Surface::WallZ1 => Vec2::new(p.x, p.y),
        }
    }
}

/// A model placed in the room.
#[derive(Debug, Clone)]
pub struct Placed {
    pub model: Model,
    /// Rotation about +y, radians; yaw 0 keeps the model's front towards +z.
    pub yaw: f32,
    pub scale: f32,
    /// Where the model's object-space origin (base centre) goes.
    pub position: Vec3,
}

impl Placed {
    pub fn rotation(&self) -> Quat {
        Quat::from_rotation_y(self.yaw)
    }

    /// World-space axis-aligned bounds.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let (lo, hi) = (self.model.mesh.min, self.model.mesh.max);
        let r = self.rotation();
        let mut out = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let w = self.position + r * (c * self.scale);
            out = (out.0.min(w), out.1.max(w));
        }
        out
    }

    pub fn footprint(&self) -> Footprint {
        let (lo, hi) = (self.model.mesh.min, self.model.mesh.max);
        let centre = Vec3::new(0.5 * (lo.x + hi.x), 0.0, 0.5 * (lo.z + hi.z)) * self.scale;
        let c = self.position + self.rotation() * centre;
        Footprint {
            centre: Vec2::new(c.x, c.z),
            half: Vec2::new(0.5 * (hi.x - lo.x), 0.5 * (hi.z - lo.z)) * self.scale,
            yaw: self.yaw,
        }
    }

    /// Height of the top surface in world coordinates, where the model offers one.
    pub fn top(&self) -> Option<f32> {
        self.model.top.map(|t| self.position.y + t * self.scale)
    }
}

/// An oriented rectangle on the floor plane (x, z).
#[derive(Debug, Clone, Copy)]
pub struct Footprint {
    pub centre: Vec2,
    pub half: Vec2,
    pub yaw: f32,
}

impl Footprint {
    /// The rectangle's local axes in (x, z): the image of +x and +z under the yaw.
    fn axes(&self) -> [Vec2; 2] {
        let (s, c) = self.yaw.sin_cos();
        [Vec2::new(c, -s), Vec2::new(s, c)]
    }

    pub fn corners(&self) -> [Vec2; 4] {
        let [a, b] = self.axes();
        let (u, v) = (a * self.half.x, b * self.half.y);
        [self.centre - u - v, self.centre + u - v, self.centre + u + v, self.centre - u + v]
    }

    /// Separating-axis test, with `gap` metres of clearance required.
    pub fn overlaps(&self, other: &Footprint, gap: f32) -> bool {
        let axes = [self.axes(), other.axes()];
        axes.iter().flatten().all(|axis| {
            let project = |f: &Footprint| {
                let [a, b] = f.axes();
                let r = f.half.x * a.dot(*axis).abs() + f.half.y * b.dot(*axis).abs();
                let c = f.centre.dot(*axis);
                (c - r, c + r)
            };
            let (a0, a1) = project(self);
            let (b0, b1) = project(other);
            a0 < b1 + gap && b0 < a1 + gap
        })
    }

    /// Whether the rectangle lies inside [m, W−m] × [m, D−m].
    pub fn inside(&self, room: Vec3, margin: f32) -> bool {
        self.corners().iter().all(|c| {
            c.x >= margin && c.y >= margin && c.x <= room.x - margin && c.y <= room.z - margin
        })
    }

    /// Whether the point lies inside the rectangle grown by `grow`.
    pub fn contains(&self, p: Vec2, grow: f32) -> bool {
        let [a, b] = self.axes();
        let d = p - self.centre;
        d.dot(a).abs() <= self.half.x + grow && d.dot(b).abs() <= self.half.y + grow
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn footprint_overlap_respects_rotation() {
        let a = Footprint { centre: Vec2::ZERO, half: Vec2::new(1.0, 0.1), yaw: 0.0 };
        let b = Footprint { centre: Vec2::new(0.0, 0.5), half: Vec2::new(1.0, 0.1), yaw: 0.0 };
        assert!(!a.overlaps(&b, 0.0));
        let c = Footprint { yaw: std::f32::consts::FRAC_PI_2, ..b };
        assert!(a.overlaps(&c, 0.0), "rotated by 90° it reaches down to the first one");
        assert!(a.overlaps(&b, 0.4), "a 0.4 m gap is required");
        assert!(a.contains(Vec2::new(0.9, 0.05), 0.0) && !a.contains(Vec2::new(0.0, 0.3), 0.1));
    }
}
