//! Furnishing a room: a room kind (dining, living, bedroom, office, mixed) picks the main
//! groups — chairs around a table, a sofa facing a coffee table and a TV, a bed between
//! nightstands, desks with chairs — then singles and rows (bookcases side by side, stools,
//! plants, lamps, pictures on the walls) fill up to the object count. Groups reuse one model
//! for their repeated members, so neighbouring chairs share a category. Every floor object
//! keeps clear of the walls and of every other footprint; small things stand on the top of
//! tables, desks, nightstands and cabinets. Models come from the catalog or from primitives.

use std::f32::consts::{FRAC_PI_2, PI};

use glam::{Vec2, Vec3};
use rand::Rng;
use rand::seq::IndexedRandom;

use super::catalog::Catalog;
use super::furniture::Model;
use super::primitives;
use super::room::{Footprint, Placed, Room};
use super::{Reserved, SynthConfig};

/// Where models come from for one scene.
pub struct Source<'a> {
    pub catalog: Option<&'a Catalog>,
    pub reserved: Reserved,
    pub mesh_share: f32,
    pub contrast: f32,
}

impl Source<'_> {
    /// A random model of `label`; `small` asks for one that fits on a table.
    pub fn model(&self, label: &str, small: bool, rng: &mut impl Rng) -> Option<Model> {
        let candidates: Vec<_> = self
            .catalog
            .map(|c| {
                c.entries
                    .iter()
                    .filter(|e| {
                        e.label == label
                            && self.reserved.allows(e.reserved)
                            && fits(e.size, label, small)
                    })
                    .collect()
            })
            .unwrap_or_default();
        let buildable = primitives::LABELS.contains(&label);
        let use_mesh =
            !candidates.is_empty() && (!buildable || rng.random::<f32>() < self.mesh_share);
        if use_mesh {
            let entry = candidates.choose(rng).expect("non-empty");
            // A model that cannot be loaded (too heavy, broken archive entry) is replaced by a
            // primitive; the outcome is the same on every run.
            if let Ok(m) = Model::from_entry(entry) {
                return Some(m);
            }
        }
        primitives::build(label, small, self.contrast, rng)
    }

    fn has(&self, label: &str) -> bool {
        primitives::LABELS.contains(&label)
            || self.catalog.is_some_and(|c| {
                c.entries.iter().any(|e| e.label == label && self.reserved.allows(e.reserved))
            })
    }
}

/// Whether a catalog model of `size` suits the place: on a table (`small`) or on the floor
/// (where table-top things such as a desk lamp would look lost).
fn fits(size: Vec3, label: &str, small: bool) -> bool {
    let tabletop = size.y < 0.6 && size.x.max(size.z) < 0.5;
    if small {
        tabletop
    } else {
        !(matches!(label, "lamp" | "vase" | "plant" | "tv" | "speaker" | "computer" | "fan")
            && size.y < 0.5)
    }
}

/// The furnished room.
pub struct Layout {
    pub objects: Vec<Placed>,
}

const GAP: f32 = 0.05;
const WALL_MARGIN: f32 = 0.03;

struct Planner<'a, R: Rng> {
    room: &'a Room,
    src: &'a Source<'a>,
    rng: &'a mut R,
    objects: Vec<Placed>,
    /// Floor footprints that block other floor objects (rugs and wall items do not).
    blocking: Vec<Footprint>,
    /// Per object: whether something already stands on its top.
    occupied: Vec<bool>,
}

/// Singles and rows that fill the room after the main groups.
const EXTRAS: &[&str] = &[
    "bookcase",
    "cabinet",
    "plant",
    "lamp",
    "trash can",
    "box",
    "ball",
    "vase",
    "speaker",
    "piano",
    "refrigerator",
    "washing machine",
    "radiator",
    "fireplace",
    "stool",
    "guitar",
    "fan",
    "bench",
    "wardrobe",
    "dresser",
    "chair",
    "armchair",
    "picture",
    "tv stand",
    "sink",
    "oven",
    "toilet",
    "bathtub",
    "pool table",
    "office chair",
];

pub fn furnish(room: &Room, src: &Source, cfg: &SynthConfig, rng: &mut impl Rng) -> Layout {
    let target = rng.random_range(cfg.objects.0..=cfg.objects.1.max(cfg.objects.0));
    let mut p =
        Planner { room, src, rng, objects: Vec::new(), blocking: Vec::new(), occupied: Vec::new() };
    if p.rng.random_bool(0.4) {
        p.rug();
    }
    // Room kind: dining, living, bedroom, office, or a mix.
    let mains: &[u8] = match p.rng.random_range(0..5) {
        0 => &[0],
        1 => &[1],
        2 => &[2],
        3 => &[3],
        _ => &[0, 1, 3],
    };
    for &main in mains {
        if p.objects.len() < target {
            match main {
                0 => p.dining(),
                1 => p.living(),
                2 => p.bedroom(),
                _ => p.office(),
            }
        }
    }
    let mut attempts = 0;
    while p.objects.len() < target && attempts < 60 {
        attempts += 1;
        if !p.objects.is_empty() && p.rng.random::<f32>() < cfg.repeat {
            p.repeat_one();
            continue;
        }
        let label = *EXTRAS.choose(p.rng).expect("extras");
        if !p.src.has(label) {
            continue;
        }
        match label {
            "picture" => p.on_wall("picture"),
            "bookcase" | "wardrobe" | "cabinet" | "dresser" | "piano" | "refrigerator"
            | "washing machine" | "radiator" | "fireplace" | "tv stand" | "sink" | "oven"
            | "toilet" | "bathtub" => p.row_along_wall(label),
            "stool" | "speaker" | "box" | "chair" | "office chair" => p.cluster(label, 2, 4),
            _ => p.single(label),
        }
    }
    p.dress_tops();
    Layout { objects: p.objects }
}

impl<R: Rng> Planner<'_, R> {
    fn scale(&mut self, model: &Model) -> f32 {
        if model.credit.is_some() { self.rng.random_range(0.9..1.1) } else { 1.0 }
    }

    /// Places `model` if it fits; returns its index.
    fn try_place(
        &mut self,
        model: &Model,
        position: Vec3,
        yaw: f32,
        scale: f32,
        blocks: bool,
    ) -> Option<usize> {
        let placed = Placed { model: model.clone(), yaw, scale, position };
        let fp = placed.footprint();
        let margin = if blocks { WALL_MARGIN } else { 0.0 };
        if !fp.inside(self.room.size, margin)
            || (blocks && self.blocking.iter().any(|b| b.overlaps(&fp, GAP)))
        {
            return None;
        }
        if placed.bounds().1.y > self.room.size.y - 0.05 {
            return None;
        }
        if blocks {
            self.blocking.push(fp);
        }
        self.objects.push(placed);
        self.occupied.push(false);
        Some(self.objects.len() - 1)
    }

    /// A point and yaw with the model's back against a random wall.
    fn against_wall(&mut self, model: &Model, scale: f32) -> (Vec3, f32) {
        let depth = (model.mesh.max.z - model.mesh.min.z) * scale;
        let back = -model.mesh.min.z * scale;
        let s = self.room.size;
        let off = back.min(depth) + WALL_MARGIN + 0.01;
        match self.rng.random_range(0..4) {
            0 => (Vec3::new(off, 0.0, self.rng.random_range(0.0..s.z)), FRAC_PI_2),
            1 => (Vec3::new(s.x - off, 0.0, self.rng.random_range(0.0..s.z)), -FRAC_PI_2),
            2 => (Vec3::new(self.rng.random_range(0.0..s.x), 0.0, off), 0.0),
            _ => (Vec3::new(self.rng.random_range(0.0..s.x), 0.0, s.z - off), PI),
        }
    }

    fn free_spot(&mut self) -> (Vec3, f32) {
        let s = self.room.size;
        let p = Vec3::new(
            self.rng.random_range(0.3..s.x - 0.3),
            0.0,
            self.rng.random_range(0.3..s.z - 0.3),
        );
        let yaw = if self.rng.random_bool(0.5) {
            self.rng.random_range(0..4) as f32 * FRAC_PI_2 + self.rng.random_range(-0.15..0.15)
        } else {
            self.rng.random_range(-PI..PI)
        };
        (p, yaw)
    }

    fn place_somewhere(&mut self, model: &Model, wall: bool) -> Option<usize> {
        let scale = self.scale(model);
        (0..25).find_map(|_| {
            let (p, yaw) = if wall { self.against_wall(model, scale) } else { self.free_spot() };
            self.try_place(model, p, yaw, scale, true)
        })
    }

    fn single(&mut self, label: &str) {
        if let Some(m) = self.src.model(label, false, self.rng) {
            let wall = self.rng.random_bool(0.5);
            self.place_somewhere(&m, wall);
        }
    }

    /// Up to `n` copies of one model side by side along a wall.
    fn row_along_wall(&mut self, label: &str) {
        let Some(m) = self.src.model(label, false, self.rng) else { return };
        let n = if matches!(label, "bookcase" | "cabinet" | "dresser") {
            self.rng.random_range(1..=3)
        } else {
            1
        };
        let scale = self.scale(&m);
        for _ in 0..25 {
            let (p, yaw) = self.against_wall(&m, scale);
            if self.try_place(&m, p, yaw, scale, true).is_none() {
                continue;
            }
            let step = (m.mesh.max.x - m.mesh.min.x) * scale + 0.02;
            let along = Vec3::new(yaw.cos(), 0.0, -yaw.sin());
            for i in 1..n {
                self.try_place(&m, p + along * step * i as f32, yaw, scale, true);
            }
            return;
        }
    }

    /// `min..=max` copies of one model loosely grouped.
    fn cluster(&mut self, label: &str, min: usize, max: usize) {
        let Some(m) = self.src.model(label, false, self.rng) else { return };
        let scale = self.scale(&m);
        let wall = self.rng.random_bool(0.3);
        let Some(first) = self.place_somewhere(&m, wall) else { return };
        let n = self.rng.random_range(min..=max);
        let (base, yaw) = (self.objects[first].position, self.objects[first].yaw);
        let spacing = (m.mesh.max - m.mesh.min).max_element() * scale + 0.1;
        let mut placed = 1;
        for _ in 0..20 {
            if placed >= n {
                break;
            }
            let a = self.rng.random_range(-PI..PI);
            let d = spacing * self.rng.random_range(1.0..1.6);
            let p = base + Vec3::new(a.cos() * d, 0.0, a.sin() * d);
            let turn = self.rng.random_range(-0.3..0.3);
            if self.try_place(&m, p, yaw + turn, scale, true).is_some() {
                placed += 1;
            }
        }
    }

    /// Another instance of a model already in the room, next to it.
    fn repeat_one(&mut self) {
        let floor: Vec<usize> = (0..self.objects.len())
            .filter(|&i| self.objects[i].position.y == 0.0 && self.objects[i].model.label != "rug")
            .collect();
        let Some(&i) = floor.choose(self.rng) else { return };
        let o = self.objects[i].clone();
        let step = (o.model.mesh.max - o.model.mesh.min).max_element() * o.scale + 0.1;
        for _ in 0..10 {
            let a = self.rng.random_range(-PI..PI);
            let p = o.position
                + Vec3::new(a.cos(), 0.0, a.sin()) * step * self.rng.random_range(1.0..1.5);
            if self.try_place(&o.model, p, o.yaw, o.scale, true).is_some() {
                return;
            }
        }
    }

    fn rug(&mut self) {
        let Some(m) = primitives::build("rug", false, self.src.contrast, self.rng) else { return };
        let s = self.room.size;
        let p = Vec3::new(
            self.rng.random_range(0.3..0.7) * s.x,
            0.0,
            self.rng.random_range(0.3..0.7) * s.z,
        );
        let yaw = self.rng.random_range(0..2) as f32 * FRAC_PI_2;
        self.try_place(&m, p, yaw, 1.0, false);
    }

    fn on_wall(&mut self, label: &str) {
        let Some(m) = self.src.model(label, false, self.rng) else { return };
        let (mut p, yaw) = self.against_wall(&m, 1.0);
        p.y = self.rng.random_range(1.1f32..1.6).min(self.room.size.y - m.mesh.max.y - 0.2);
        // Pull it back against the wall: its back is at z = 0 in object space.
        p -= Vec3::new(yaw.sin(), 0.0, yaw.cos()) * (WALL_MARGIN + 0.007);
        self.try_place(&m, p, yaw, 1.0, false);
    }

    /// `n` seats of one model around the footprint of object `anchor`, facing it.
    fn seats_around(&mut self, anchor: usize, label: &str, n: usize) {
        let Some(chair) = self.src.model(label, false, self.rng) else { return };
        let scale = self.scale(&chair);
        let a = self.objects[anchor].footprint();
        let depth = (chair.mesh.max.z - chair.mesh.min.z) * scale;
        let mut placed = 0;
        let [ax, az] = [Vec2::new(a.yaw.cos(), -a.yaw.sin()), Vec2::new(a.yaw.sin(), a.yaw.cos())];
        let slots: Vec<Vec2> = vec![
            a.centre + az * (a.half.y + 0.35 * depth),
            a.centre - az * (a.half.y + 0.35 * depth),
            a.centre + ax * (a.half.x + 0.35 * depth),
            a.centre - ax * (a.half.x + 0.35 * depth),
            a.centre + az * (a.half.y + 0.35 * depth) + ax * a.half.x * 0.5,
            a.centre - az * (a.half.y + 0.35 * depth) + ax * a.half.x * 0.5,
            a.centre + az * (a.half.y + 0.35 * depth) - ax * a.half.x * 0.5,
            a.centre - az * (a.half.y + 0.35 * depth) - ax * a.half.x * 0.5,
        ];
        let mut order: Vec<usize> = (0..slots.len()).collect();
        for i in (1..order.len()).rev() {
            order.swap(i, self.rng.random_range(0..=i));
        }
        // Seats may tuck under the table: they only need to clear each other.
        let table_fp = self.blocking.iter().position(|f| f.centre == a.centre);
        let removed = table_fp.map(|i| self.blocking.remove(i));
        for &k in &order {
            if placed >= n {
                break;
            }
            let s = slots[k];
            let to = a.centre - s;
            let yaw = to.x.atan2(to.y) + self.rng.random_range(-0.2..0.2);
            if self.try_place(&chair, Vec3::new(s.x, 0.0, s.y), yaw, scale, true).is_some() {
                placed += 1;
            }
        }
        if let Some(fp) = removed {
            self.blocking.push(fp);
        }
    }

    fn dining(&mut self) {
        let Some(table) = self.src.model("table", false, self.rng) else { return };
        let Some(t) = self.place_somewhere(&table, false) else { return };
        let n = self.rng.random_range(2..=6);
        let label = if self.rng.random_bool(0.85) { "chair" } else { "stool" };
        self.seats_around(t, label, n);
    }

    fn living(&mut self) {
        let Some(sofa) = self.src.model("sofa", false, self.rng) else { return };
        let Some(s) = self.place_somewhere(&sofa, true) else { return };
        let front = {
            let o = &self.objects[s];
            Vec3::new(o.yaw.sin(), 0.0, o.yaw.cos())
        };
        let depth = (sofa.mesh.max.z - sofa.mesh.min.z) * self.objects[s].scale;
        if let Some(ct) = self.src.model("coffee table", false, self.rng) {
            let p = self.objects[s].position + front * (0.5 * depth + 0.6);
            let yaw = self.objects[s].yaw;
            let scale = self.scale(&ct);
            if let Some(c) = self.try_place(&ct, p, yaw, scale, true) {
                let n = self.rng.random_range(0..=2);
                if n > 0 {
                    self.seats_around(c, "armchair", n);
                }
            }
        }
        if let Some(stand) = self.src.model(
            if self.rng.random_bool(0.5) { "tv stand" } else { "cabinet" },
            false,
            self.rng,
        ) {
            let p = self.objects[s].position + front * self.rng.random_range(2.2..3.2);
            let scale = self.scale(&stand);
            if let Some(i) = self.try_place(&stand, p, self.objects[s].yaw + PI, scale, true) {
                self.put_on(i, "tv");
            }
        }
    }

    fn bedroom(&mut self) {
        let Some(bed) = self.src.model("bed", false, self.rng) else { return };
        let scale = self.scale(&bed);
        for _ in 0..25 {
            let (p, yaw) = self.against_wall(&bed, scale);
            let Some(b) = self.try_place(&bed, p, yaw, scale, true) else { continue };
            let Some(ns) = self.src.model("nightstand", false, self.rng) else { return };
            let ns_scale = self.scale(&ns);
            let half_w = 0.5 * (bed.mesh.max.x - bed.mesh.min.x) * scale;
            let ns_half = 0.5 * (ns.mesh.max.x - ns.mesh.min.x) * ns_scale;
            let along = Vec3::new(yaw.cos(), 0.0, -yaw.sin());
            let front = Vec3::new(yaw.sin(), 0.0, yaw.cos());
            let back = self.objects[b].position
                + front * (bed.mesh.min.z * scale - ns.mesh.min.z * ns_scale);
            for side in [-1.0f32, 1.0] {
                let p = back + along * side * (half_w + ns_half + 0.05);
                if let Some(i) = self.try_place(&ns, p, yaw, ns_scale, true) {
                    self.put_on(i, "lamp");
                }
            }
            return;
        }
    }

    fn office(&mut self) {
        let Some(desk) = self.src.model("desk", false, self.rng) else { return };
        let seat = if self.src.has("office chair") && self.rng.random_bool(0.7) {
            "office chair"
        } else {
            "chair"
        };
        let Some(chair) = self.src.model(seat, false, self.rng) else { return };
        let n = self.rng.random_range(1..=3);
        let (scale, chair_scale) = (self.scale(&desk), self.scale(&chair));
        for _ in 0..n {
            for _ in 0..25 {
                let (p, yaw) = self.against_wall(&desk, scale);
                let Some(d) = self.try_place(&desk, p, yaw, scale, true) else { continue };
                let front = Vec3::new(yaw.sin(), 0.0, yaw.cos());
                let reach = desk.mesh.max.z * scale + 0.15;
                let cp = self.objects[d].position + front * reach;
                // The chair may tuck under its desk: it only has to clear everything else.
                let desk_fp = self.blocking.pop();
                let turn = self.rng.random_range(-0.4..0.4);
                self.try_place(&chair, cp, yaw + PI + turn, chair_scale, true);
                self.blocking.extend(desk_fp);
                let small = *["computer", "lamp", "tv", "plant"].choose(self.rng).expect("labels");
                self.put_on(d, small);
                break;
            }
        }
    }

    /// Puts a small `label` on the top of object `i`, if it offers one and has room.
    fn put_on(&mut self, i: usize, label: &str) -> bool {
        let Some(top) = self.objects[i].top() else { return false };
        if self.occupied[i] || top > self.room.size.y - 0.8 {
            return false;
        }
        let Some(m) = self.src.model(label, true, self.rng) else { return false };
        let base = self.objects[i].footprint();
        let scale = self.scale(&m);
        let half =
            Vec2::new(m.mesh.max.x - m.mesh.min.x, m.mesh.max.z - m.mesh.min.z) * 0.5 * scale;
        if half.x.max(half.y) > base.half.x.min(base.half.y) {
            return false;
        }
        let yaw = base.yaw + self.rng.random_range(-0.4..0.4);
        let slack = (base.half - Vec2::splat(half.max_element())).max(Vec2::ZERO);
        let (sy, cy) = base.yaw.sin_cos();
        let local = Vec2::new(
            self.rng.random_range(-1.0..=1.0) * slack.x,
            self.rng.random_range(-1.0..=1.0) * slack.y,
        );
        let c = base.centre + Vec2::new(cy, -sy) * local.x + Vec2::new(sy, cy) * local.y;
        if self.try_place(&m, Vec3::new(c.x, top, c.y), yaw, scale, false).is_some() {
            self.occupied[i] = true;
            return true;
        }
        false
    }

    /// Small things on tops that are still free.
    fn dress_tops(&mut self) {
        for i in 0..self.objects.len() {
            if self.objects[i].position.y == 0.0 && self.rng.random_bool(0.5) {
                let label = *["vase", "lamp", "plant", "box", "speaker", "computer"]
                    .choose(self.rng)
                    .expect("labels");
                if self.src.has(label) {
                    self.put_on(i, label);
                }
            }
        }
    }
}
