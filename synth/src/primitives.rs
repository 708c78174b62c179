//! Furniture built from boxes, cylinders, cones and ellipsoids: random sizes, proportions
//! and materials for twenty categories, in the same object-space convention as catalog
//! meshes (metres, base at y = 0, centred, front towards +z). They are cheap (tens to a few
//! hundred triangles), need no furniture folder, and widen the shape distribution beyond
//! the catalog's few hundred models.

use std::sync::Arc;

use glam::{Vec2, Vec3};
use rand::Rng;
use rand::seq::IndexedRandom;

use super::furniture::Model;
use super::mesh::{Material, MeshBuilder};
use super::texture::{Pattern, PatternKind, jitter_colour, srgb_to_linear};

/// Categories this module can build.
pub const LABELS: &[&str] = &[
    "table",
    "coffee table",
    "desk",
    "nightstand",
    "cabinet",
    "bookcase",
    "chair",
    "stool",
    "armchair",
    "sofa",
    "bed",
    "lamp",
    "plant",
    "vase",
    "box",
    "trash can",
    "tv",
    "ball",
    "rug",
    "picture",
];

/// Builds a random object of `label` (one of [`LABELS`]); `small` asks for the variant that
/// stands on furniture (table lamp, small plant) where one exists.
pub fn build(label: &str, small: bool, contrast: f32, rng: &mut impl Rng) -> Option<Model> {
    let mut s = Shop { b: MeshBuilder::default(), contrast };
    let top = match label {
        "table" => {
            let (h, size) = (
                rng.random_range(0.72..0.78),
                Vec2::new(rng.random_range(0.8..1.8), rng.random_range(0.7..1.0)),
            );
            s.table(rng, h, size)
        }
        "coffee table" => {
            let (h, size) = (
                rng.random_range(0.35..0.5),
                Vec2::new(rng.random_range(0.6..1.2), rng.random_range(0.45..0.7)),
            );
            s.table(rng, h, size)
        }
        "desk" => s.desk(rng),
        "nightstand" => {
            let size = Vec3::new(
                rng.random_range(0.38..0.55),
                rng.random_range(0.45..0.62),
                rng.random_range(0.35..0.45),
            );
            s.chest(rng, size, 2)
        }
        "cabinet" => {
            let size = Vec3::new(
                rng.random_range(0.6..1.3),
                rng.random_range(0.75..1.25),
                rng.random_range(0.38..0.55),
            );
            s.chest(rng, size, 0)
        }
        "bookcase" => s.bookcase(rng),
        "chair" => s.chair(rng),
        "stool" => s.stool(rng),
        "armchair" => s.sofa(rng, 1),
        "sofa" => {
            let seats = rng.random_range(2..=3);
            s.sofa(rng, seats)
        }
        "bed" => s.bed(rng),
        "lamp" => s.lamp(rng, small),
        "plant" => s.plant(rng, small),
        "vase" => s.vase(rng),
        "box" => s.crate_box(rng, small),
        "trash can" => s.bin(rng),
        "tv" => s.tv(rng),
        "ball" => s.ball(rng),
        "rug" => s.rug(rng),
        "picture" => s.picture(rng),
        _ => return None,
    };
    let label = LABELS.iter().copied().find(|l| *l == label)?;
    Some(Model { mesh: Arc::new(s.b.build()), label, credit: None, top })
}

fn srgb(r: u8, g: u8, b: u8) -> Vec3 {
    srgb_to_linear(Vec3::new(r as f32, g as f32, b as f32) / 255.0)
}

struct Shop {
    b: MeshBuilder,
    contrast: f32,
}

impl Shop {
    fn wood(&mut self, rng: &mut impl Rng) -> u16 {
        let tones = [
            srgb(196, 154, 108),
            srgb(140, 94, 60),
            srgb(92, 60, 40),
            srgb(222, 196, 160),
            srgb(60, 42, 30),
        ];
        let tone = *tones.choose(rng).expect("tones");
        let base = jitter_colour(rng, tone, 0.1);
        let p = Pattern::random(rng, PatternKind::WoodGrain, base, self.contrast);
        self.b.material(Material::patterned(p))
    }

    fn paint(&mut self, rng: &mut impl Rng) -> u16 {
        let palette = [
            srgb(240, 240, 235),
            srgb(40, 40, 42),
            srgb(180, 60, 50),
            srgb(60, 90, 150),
            srgb(90, 140, 90),
            srgb(230, 200, 90),
            srgb(150, 150, 155),
        ];
        let pick = *palette.choose(rng).expect("palette");
        let c = jitter_colour(rng, pick, 0.15);
        self.b.material(Material::flat(c))
    }

    fn fabric(&mut self, rng: &mut impl Rng) -> u16 {
        let base = Vec3::new(
            rng.random_range(0.03..0.6),
            rng.random_range(0.03..0.6),
            rng.random_range(0.03..0.6),
        );
        let kind = *[PatternKind::Carpet, PatternKind::Noise, PatternKind::Stripes]
            .choose(rng)
            .expect("kinds");
        let p = Pattern::random(rng, kind, base, self.contrast * 0.6);
        self.b.material(Material::patterned(p))
    }

    fn flat(&mut self, c: Vec3) -> u16 {
        self.b.material(Material::flat(c))
    }

    /// Four legs under a rectangle of `size` (x, z), inset by `inset`.
    fn legs(&mut self, size: Vec2, height: f32, thick: f32, inset: f32, round: bool, m: u16) {
        for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let c = Vec3::new(sx * (0.5 * size.x - inset), 0.0, sz * (0.5 * size.y - inset));
            if round {
                self.b.frustum(c, 0.5 * thick, 0.5 * thick, height, 8, m);
            } else {
                self.b.cuboid(
                    c - Vec3::new(thick, 0.0, thick) * 0.5,
                    c + Vec3::new(thick * 0.5, height, thick * 0.5),
                    m,
                );
            }
        }
    }

    fn table(&mut self, rng: &mut impl Rng, h: f32, size: Vec2) -> Option<f32> {
        let top = if rng.random_bool(0.7) { self.wood(rng) } else { self.paint(rng) };
        let legs = if rng.random_bool(0.5) { top } else { self.paint(rng) };
        let t = rng.random_range(0.025..0.05);
        if rng.random_bool(0.25) {
            // Round table on a pedestal.
            let r = 0.5 * size.x.min(1.2);
            self.b.frustum(Vec3::new(0.0, h - t, 0.0), r, r, t, 24, top);
            self.b.frustum(Vec3::ZERO, 0.04, 0.04, h - t, 8, legs);
            self.b.frustum(Vec3::ZERO, 0.25 * r, 0.2 * r, 0.03, 12, legs);
        } else {
            self.b.cuboid(
                Vec3::new(-0.5 * size.x, h - t, -0.5 * size.y),
                Vec3::new(0.5 * size.x, h, 0.5 * size.y),
                top,
            );
            self.legs(size, h - t, rng.random_range(0.035..0.07), 0.06, rng.random_bool(0.4), legs);
        }
        Some(h)
    }

    fn desk(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let size = Vec2::new(rng.random_range(1.0..1.6), rng.random_range(0.55..0.8));
        let h = rng.random_range(0.72..0.77);
        self.table(rng, h, size);
        let m = self.paint(rng);
        let w = rng.random_range(0.35..0.45);
        let x0 = 0.5 * size.x - w - 0.02;
        self.b.cuboid(
            Vec3::new(x0, 0.0, -0.5 * size.y + 0.03),
            Vec3::new(x0 + w, h - 0.05, 0.5 * size.y - 0.03),
            m,
        );
        Some(h)
    }

    /// A box of drawers/doors; `drawers` = 0 draws two doors.
    fn chest(&mut self, rng: &mut impl Rng, size: Vec3, drawers: u32) -> Option<f32> {
        let body = if rng.random_bool(0.5) { self.wood(rng) } else { self.paint(rng) };
        let front = if rng.random_bool(0.5) { body } else { self.paint(rng) };
        let knob = self.flat(srgb(190, 190, 195) * rng.random_range(0.5..1.0));
        let (w, h, d) = (size.x, size.y, size.z);
        self.b.cuboid(Vec3::new(-0.5 * w, 0.05, -0.5 * d), Vec3::new(0.5 * w, h, 0.5 * d), body);
        self.b.cuboid(
            Vec3::new(-0.5 * w + 0.03, 0.0, -0.5 * d + 0.03),
            Vec3::new(0.5 * w - 0.03, 0.05, 0.5 * d - 0.03),
            knob,
        );
        let gap = 0.012;
        if drawers > 0 {
            let dh = (h - 0.08) / drawers as f32;
            for i in 0..drawers {
                let y0 = 0.07 + i as f32 * dh;
                self.b.cuboid(
                    Vec3::new(-0.5 * w + 0.02, y0 + gap, 0.5 * d),
                    Vec3::new(0.5 * w - 0.02, y0 + dh - gap, 0.5 * d + 0.015),
                    front,
                );
                self.b.ellipsoid(
                    Vec3::new(0.0, y0 + 0.5 * dh, 0.5 * d + 0.025),
                    Vec3::splat(0.015),
                    4,
                    6,
                    knob,
                );
            }
        } else {
            for sx in [-1.0f32, 1.0] {
                let (x0, x1) =
                    if sx < 0.0 { (-0.5 * w + 0.02, -gap) } else { (gap, 0.5 * w - 0.02) };
                self.b.cuboid(
                    Vec3::new(x0, 0.08, 0.5 * d),
                    Vec3::new(x1, h - 0.03, 0.5 * d + 0.015),
                    front,
                );
                self.b.cuboid(
                    Vec3::new(sx * 0.05 - 0.01, 0.5 * h, 0.5 * d + 0.015),
                    Vec3::new(sx * 0.05 + 0.01, 0.5 * h + 0.12, 0.5 * d + 0.035),
                    knob,
                );
            }
        }
        Some(h)
    }

    fn bookcase(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let (w, h, d) =
            (rng.random_range(0.6..1.2), rng.random_range(0.9..2.1), rng.random_range(0.28..0.4));
        let m = if rng.random_bool(0.6) { self.wood(rng) } else { self.paint(rng) };
        let t = 0.025;
        self.b.cuboid(Vec3::new(-0.5 * w, 0.0, -0.5 * d), Vec3::new(-0.5 * w + t, h, 0.5 * d), m);
        self.b.cuboid(Vec3::new(0.5 * w - t, 0.0, -0.5 * d), Vec3::new(0.5 * w, h, 0.5 * d), m);
        self.b.cuboid(
            Vec3::new(-0.5 * w, 0.0, -0.5 * d),
            Vec3::new(0.5 * w, h, -0.5 * d + 0.01),
            m,
        );
        let shelves = ((h / 0.35) as u32).max(2);
        let book_colours: Vec<u16> = (0..4).map(|_| self.paint(rng)).collect();
        for i in 0..=shelves {
            let y = i as f32 * (h - t) / shelves as f32;
            self.b.cuboid(Vec3::new(-0.5 * w, y, -0.5 * d), Vec3::new(0.5 * w, y + t, 0.5 * d), m);
            if i == shelves || rng.random_bool(0.25) {
                continue;
            }
            // A row of books.
            let mut x = -0.5 * w + t + 0.01;
            let limit = 0.5 * w - t - rng.random_range(0.0..0.4 * w);
            while x < limit - 0.03 {
                let bw = rng.random_range(0.02..0.05);
                let bh = rng.random_range(0.17f32..0.28).min((h - t) / shelves as f32 - 0.03);
                let c = *book_colours.choose(rng).expect("colours");
                self.b.cuboid(
                    Vec3::new(x, y + t, -0.5 * d + 0.02),
                    Vec3::new(x + bw, y + t + bh, 0.5 * d - 0.03),
                    c,
                );
                x += bw + 0.003;
            }
        }
        (h < 1.3).then_some(h)
    }

    fn chair(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let (w, d) = (rng.random_range(0.4..0.5), rng.random_range(0.4..0.5));
        let seat_h = rng.random_range(0.42..0.48);
        let back_h = rng.random_range(0.35..0.5);
        let frame = if rng.random_bool(0.6) { self.wood(rng) } else { self.paint(rng) };
        let seat = if rng.random_bool(0.5) { frame } else { self.fabric(rng) };
        let t = 0.04;
        self.b.cuboid(
            Vec3::new(-0.5 * w, seat_h - t, -0.5 * d),
            Vec3::new(0.5 * w, seat_h, 0.5 * d),
            seat,
        );
        self.legs(Vec2::new(w, d), seat_h - t, 0.035, 0.03, rng.random_bool(0.4), frame);
        self.b.cuboid(
            Vec3::new(-0.5 * w, seat_h, -0.5 * d),
            Vec3::new(0.5 * w, seat_h + back_h, -0.5 * d + 0.03),
            frame,
        );
        None
    }

    fn stool(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let h = rng.random_range(0.45..0.8);
        let r = rng.random_range(0.15..0.2);
        let seat = if rng.random_bool(0.5) { self.wood(rng) } else { self.fabric(rng) };
        let legs = self.paint(rng);
        self.b.frustum(Vec3::new(0.0, h - 0.05, 0.0), r, r, 0.05, 16, seat);
        if rng.random_bool(0.5) {
            self.b.frustum(Vec3::ZERO, 0.03, 0.03, h - 0.05, 8, legs);
            self.b.frustum(Vec3::ZERO, r * 0.9, r * 0.8, 0.025, 16, legs);
        } else {
            self.legs(Vec2::splat(1.4 * r), h - 0.05, 0.03, 0.0, true, legs);
        }
        Some(h)
    }

    /// Sofa with `seats` cushions (1 = armchair).
    fn sofa(&mut self, rng: &mut impl Rng, seats: u32) -> Option<f32> {
        let seat_w = rng.random_range(0.55..0.7);
        let arm = rng.random_range(0.1..0.2);
        let w = seats as f32 * seat_w + 2.0 * arm;
        let d = rng.random_range(0.8..0.95);
        let (base_h, seat_h, back_h) = (
            rng.random_range(0.15..0.25),
            rng.random_range(0.4..0.46),
            rng.random_range(0.75..0.9),
        );
        let cloth = self.fabric(rng);
        let cushion = if rng.random_bool(0.6) { cloth } else { self.fabric(rng) };
        let feet = self.paint(rng);
        self.legs(Vec2::new(w, d), 0.06, 0.04, 0.05, true, feet);
        self.b.cuboid(
            Vec3::new(-0.5 * w, 0.06, -0.5 * d),
            Vec3::new(0.5 * w, 0.06 + base_h, 0.5 * d),
            cloth,
        );
        self.b.cuboid(
            Vec3::new(-0.5 * w, 0.06, -0.5 * d),
            Vec3::new(0.5 * w, back_h, -0.5 * d + 0.2),
            cloth,
        );
        for sx in [-1.0f32, 1.0] {
            let x = sx * 0.5 * w;
            self.b.cuboid(
                Vec3::new(x.min(x - sx * arm), 0.06, -0.5 * d),
                Vec3::new(x.max(x - sx * arm), seat_h + 0.18, 0.5 * d),
                cloth,
            );
        }
        for i in 0..seats {
            let x0 = -0.5 * w + arm + i as f32 * seat_w;
            self.b.cuboid(
                Vec3::new(x0 + 0.01, 0.06 + base_h, -0.5 * d + 0.2),
                Vec3::new(x0 + seat_w - 0.01, seat_h, 0.5 * d),
                cushion,
            );
        }
        None
    }

    fn bed(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let w = *[0.9f32, 1.4, 1.6, 1.8].choose(rng).expect("widths") + rng.random_range(0.0..0.1);
        let l = rng.random_range(1.95..2.15);
        let frame = if rng.random_bool(0.6) { self.wood(rng) } else { self.paint(rng) };
        let sheet = self.flat(jitter_colour(rng, srgb(235, 232, 225), 0.08));
        let blanket = self.fabric(rng);
        let fh = rng.random_range(0.25..0.35);
        self.b.cuboid(Vec3::new(-0.5 * w, 0.0, -0.5 * l), Vec3::new(0.5 * w, fh, 0.5 * l), frame);
        self.b.cuboid(
            Vec3::new(-0.5 * w + 0.03, fh, -0.5 * l + 0.05),
            Vec3::new(0.5 * w - 0.03, fh + 0.2, 0.5 * l - 0.03),
            sheet,
        );
        self.b.cuboid(
            Vec3::new(-0.5 * w, fh + 0.1, -0.15 * l),
            Vec3::new(0.5 * w, fh + 0.23, 0.5 * l),
            blanket,
        );
        self.b.cuboid(
            Vec3::new(-0.5 * w, 0.0, -0.5 * l),
            Vec3::new(0.5 * w, rng.random_range(0.8..1.1), -0.5 * l + 0.06),
            frame,
        );
        let pillows = if w > 1.2 { 2 } else { 1 };
        for i in 0..pillows {
            let x = if pillows == 1 { 0.0 } else { (i as f32 - 0.5) * 0.5 * w };
            self.b.ellipsoid(
                Vec3::new(x, fh + 0.26, -0.5 * l + 0.3),
                Vec3::new(0.3, 0.07, 0.18),
                6,
                12,
                sheet,
            );
        }
        None
    }

    fn lamp(&mut self, rng: &mut impl Rng, small: bool) -> Option<f32> {
        let metal = self.paint(rng);
        let shade = self.flat(jitter_colour(rng, srgb(240, 228, 200), 0.12));
        let h = if small { rng.random_range(0.3..0.55) } else { rng.random_range(1.3..1.8) };
        let base_r = if small { 0.08 } else { 0.16 };
        self.b.frustum(Vec3::ZERO, base_r, base_r * 0.8, 0.03, 16, metal);
        self.b.frustum(Vec3::ZERO, 0.012, 0.012, h * 0.8, 8, metal);
        let sr = if small { rng.random_range(0.1..0.16) } else { rng.random_range(0.18..0.26) };
        self.b.frustum(
            Vec3::new(0.0, h * 0.72, 0.0),
            sr,
            sr * rng.random_range(0.55..0.9),
            h * 0.28,
            16,
            shade,
        );
        None
    }

    fn plant(&mut self, rng: &mut impl Rng, small: bool) -> Option<f32> {
        let pot = if rng.random_bool(0.5) {
            self.paint(rng)
        } else {
            self.flat(jitter_colour(rng, srgb(170, 90, 60), 0.15))
        };
        let leaf = self.flat(jitter_colour(rng, srgb(60, 110, 50), 0.3));
        let s = if small { 0.4 } else { 1.0 };
        let (pr, ph) = (rng.random_range(0.12..0.22) * s, rng.random_range(0.2..0.4) * s);
        self.b.frustum(Vec3::ZERO, pr * 0.75, pr, ph, 14, pot);
        let crown = rng.random_range(0.4..1.3) * s;
        for _ in 0..rng.random_range(3..7) {
            let c = Vec3::new(
                rng.random_range(-0.5..0.5) * pr * 1.5,
                ph + rng.random_range(0.3..1.0) * crown,
                rng.random_range(-0.5..0.5) * pr * 1.5,
            );
            let r = Vec3::new(
                rng.random_range(0.6..1.0),
                rng.random_range(0.6..1.2),
                rng.random_range(0.6..1.0),
            ) * crown
                * 0.3;
            self.b.ellipsoid(c, r, 6, 10, leaf);
        }
        None
    }

    fn vase(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let m = self.paint(rng);
        let (r, h) = (rng.random_range(0.06..0.14), rng.random_range(0.2..0.6));
        self.b.ellipsoid(Vec3::new(0.0, 0.45 * h, 0.0), Vec3::new(r, 0.45 * h, r), 8, 14, m);
        self.b.frustum(Vec3::new(0.0, 0.8 * h, 0.0), 0.5 * r, 0.6 * r, 0.2 * h, 12, m);
        None
    }

    fn crate_box(&mut self, rng: &mut impl Rng, small: bool) -> Option<f32> {
        let m = if rng.random_bool(0.5) {
            self.wood(rng)
        } else {
            self.flat(jitter_colour(rng, srgb(190, 150, 105), 0.1))
        };
        let shrink = if small { 0.4 } else { 1.0 };
        let s = Vec3::new(
            rng.random_range(0.25..0.7),
            rng.random_range(0.2..0.5),
            rng.random_range(0.25..0.6),
        ) * shrink;
        self.b.cuboid(
            Vec3::new(-0.5 * s.x, 0.0, -0.5 * s.z),
            Vec3::new(0.5 * s.x, s.y, 0.5 * s.z),
            m,
        );
        Some(s.y)
    }

    fn bin(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let m = self.paint(rng);
        let (r, h) = (rng.random_range(0.1..0.18), rng.random_range(0.3..0.5));
        self.b.frustum(Vec3::ZERO, r * 0.85, r, h, 16, m);
        None
    }

    fn tv(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let body = self.flat(srgb(25, 25, 28));
        let screen = self.flat(jitter_colour(rng, srgb(20, 24, 32), 0.2));
        let w = rng.random_range(0.6..1.2);
        let h = w * 0.5625;
        self.b.cuboid(Vec3::new(-0.15, 0.0, -0.1), Vec3::new(0.15, 0.02, 0.1), body);
        self.b.cuboid(Vec3::new(-0.03, 0.0, -0.03), Vec3::new(0.03, 0.1, 0.0), body);
        self.b.cuboid(Vec3::new(-0.5 * w, 0.08, -0.03), Vec3::new(0.5 * w, 0.08 + h, 0.02), body);
        self.b.cuboid(
            Vec3::new(-0.5 * w + 0.015, 0.095, 0.02),
            Vec3::new(0.5 * w - 0.015, 0.065 + h, 0.025),
            screen,
        );
        None
    }

    fn ball(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let m = self.paint(rng);
        let r = rng.random_range(0.1..0.2);
        self.b.ellipsoid(Vec3::new(0.0, r, 0.0), Vec3::splat(r), 10, 16, m);
        None
    }

    fn rug(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let m = self.fabric(rng);
        let (w, d) = (rng.random_range(1.0..2.4), rng.random_range(0.7..1.8));
        self.b.cuboid(Vec3::new(-0.5 * w, 0.0, -0.5 * d), Vec3::new(0.5 * w, 0.012, 0.5 * d), m);
        None
    }

    fn picture(&mut self, rng: &mut impl Rng) -> Option<f32> {
        let frame = if rng.random_bool(0.5) { self.wood(rng) } else { self.paint(rng) };
        let base = Vec3::new(
            rng.random_range(0.1..0.9),
            rng.random_range(0.1..0.9),
            rng.random_range(0.1..0.9),
        );
        let art = Pattern::random(rng, PatternKind::Noise, base, 2.0);
        let art = self.b.material(Material::patterned(art));
        let (w, h) = (rng.random_range(0.3..0.9), rng.random_range(0.3..0.7));
        self.b.cuboid(Vec3::new(-0.5 * w, 0.0, 0.0), Vec3::new(0.5 * w, h, 0.03), frame);
        self.b.cuboid(
            Vec3::new(-0.5 * w + 0.04, 0.04, 0.03),
            Vec3::new(0.5 * w - 0.04, h - 0.04, 0.035),
            art,
        );
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn every_label_builds_a_grounded_mesh() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for &label in LABELS {
            for small in [false, true] {
                let m = build(label, small, 1.0, &mut rng).unwrap();
                assert_eq!(m.label, label);
                assert!(m.mesh.triangle_count() > 0, "{label}");
                assert!(m.mesh.min.y.abs() < 1e-4, "{label} floats: {}", m.mesh.min.y);
                assert!(m.mesh.max.y < 2.5 && m.mesh.max.y > 0.005, "{label}");
            }
        }
    }
}
