//! Triangle meshes the ray caster shoots at: object-space triangles (metres, +y up, base at
//! y = 0, front towards +z), per-triangle materials (flat albedo, an optional image texture,
//! an optional procedural pattern) and a compressed-wide BVH from `obvhs` (measured against
//! the `bvh` crate: see the module docs of `synth`). Meshes come from two places — the
//! furniture catalog and [`MeshBuilder`]'s boxes, cylinders and spheres — and are immutable
//! once built, so one parsed model is shared by every instance and every thread.

use std::sync::Arc;

use glam::{Vec2, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit, safe_inverse};

use super::texture::Pattern;

/// `obvhs` brings its own glam release (whichever its version range resolves to), so its
/// vectors are filled component-wise rather than converted by type.
macro_rules! assign {
    ($dst:expr, $src:expr) => {{
        let s = $src;
        $dst.x = s.x;
        $dst.y = s.y;
        $dst.z = s.z;
    }};
}

/// An `obvhs` ray for `origin + t·dir`, `t` in (`tmin`, `tmax`).
fn bvh_ray(origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Ray {
    let mut ray = Ray::new_inf(Default::default(), Default::default());
    assign!(ray.origin, origin);
    assign!(ray.direction, dir);
    assign!(
        ray.inv_direction,
        Vec3::new(safe_inverse(dir.x), safe_inverse(dir.y), safe_inverse(dir.z))
    );
    ray.tmin = tmin;
    ray.tmax = tmax;
    ray
}

/// A decoded image texture, linear RGB, small (downsampled at load).
#[derive(Debug)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Nearest texel at `uv` (wrapping, v up as in OBJ).
    fn sample(&self, uv: Vec2) -> Vec3 {
        let x = ((uv.x.rem_euclid(1.0)) * self.width as f32) as u32;
        let y = (((1.0 - uv.y).rem_euclid(1.0)) * self.height as f32) as u32;
        self.texels[(y.min(self.height - 1) * self.width + x.min(self.width - 1)) as usize]
    }
}

/// Surface appearance: albedo × texture(uv) × pattern(uv).
#[derive(Debug, Clone)]
pub struct Material {
    /// Linear RGB albedo.
    pub albedo: Vec3,
    pub texture: Option<Arc<Texture>>,
    /// Evaluated on the triangle's uv in metres (primitives) .
    pub pattern: Option<Pattern>,
}

impl Material {
    pub fn flat(albedo: Vec3) -> Self {
        Self { albedo, texture: None, pattern: None }
    }

    pub fn patterned(pattern: Pattern) -> Self {
        Self { albedo: Vec3::ONE, texture: None, pattern: Some(pattern) }
    }

    /// Linear albedo at texture coordinate `uv`.
    pub fn shade(&self, uv: Vec2) -> Vec3 {
        let mut c = self.albedo;
        if let Some(t) = &self.texture {
            c *= t.sample(uv);
        }
        if let Some(p) = &self.pattern {
            c *= p.albedo(uv);
        }
        c
    }
}

/// A triangle prepared for intersection.
#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: Vec3A,
    e1: Vec3A,
    e2: Vec3A,
    normal: Vec3A,
    uv0: Vec2,
    duv1: Vec2,
    duv2: Vec2,
    material: u16,
}

impl Tri {
    /// Möller–Trumbore; returns (t, u, v) within the ray's range.
    #[inline(always)]
    fn intersect(
        &self,
        origin: Vec3A,
        dir: Vec3A,
        tmin: f32,
        tmax: f32,
    ) -> Option<(f32, f32, f32)> {
        let p = dir.cross(self.e2);
        let det = self.e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv = 1.0 / det;
        let s = origin - self.v0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = dir.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        (t > tmin && t < tmax).then_some((t, u, v))
    }
}

/// Where a ray met a mesh, in object space.
#[derive(Debug, Clone, Copy)]
pub struct MeshHit {
    pub t: f32,
    /// Geometric normal (unit, not flipped towards the ray).
    pub normal: Vec3,
    pub uv: Vec2,
    pub material: u16,
}

/// An immutable mesh with its BVH.
#[derive(Debug)]
pub struct Mesh {
    tris: Vec<Tri>,
    bvh: CwBvh,
    pub materials: Vec<Material>,
    /// Object-space bounds.
    pub min: Vec3,
    pub max: Vec3,
}

impl Mesh {
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Closest hit of `origin + t·dir`, `t` in (`tmin`, `tmax`). `dir` need not be unit length;
    /// `t` is in units of `dir`.
    pub fn closest(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<MeshHit> {
        let ray = bvh_ray(origin, dir, tmin, tmax);
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        let mut best: Option<(usize, f32, f32, f32)> = None;
        let mut hit = RayHit::none();
        self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            match self.tris[id].intersect(o, d, r.tmin, r.tmax) {
                Some((t, u, v)) => {
                    best = Some((id, t, u, v));
                    t
                }
                None => f32::INFINITY,
            }
        });
        let (id, t, u, v) = best?;
        let tri = &self.tris[id];
        Some(MeshHit {
            t,
            normal: tri.normal.into(),
            uv: tri.uv0 + u * tri.duv1 + v * tri.duv2,
            material: tri.material,
        })
    }

    /// Whether anything lies on the segment `origin + t·dir`, `t` in (`tmin`, `tmax`).
    pub fn occludes(&self, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> bool {
        let ray = bvh_ray(origin, dir, tmin, tmax);
        let (o, d) = (Vec3A::from(origin), Vec3A::from(dir));
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            self.tris[id].intersect(o, d, r.tmin, r.tmax).map_or(f32::INFINITY, |h| h.0)
        })
    }
}

/// Collects triangles, then builds a [`Mesh`]. Also the home of the primitive shapes.
#[derive(Debug, Default, Clone)]
pub struct MeshBuilder {
    positions: Vec<Vec3>,
    uvs: Vec<Vec2>,
    /// Corner indices into `positions`/`uvs` and the material per triangle.
    tris: Vec<([u32; 3], u16)>,
    materials: Vec<Material>,
}

impl MeshBuilder {
    pub fn material(&mut self, m: Material) -> u16 {
        self.materials.push(m);
        (self.materials.len() - 1) as u16
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Adds a triangle with its own corners.
    pub fn triangle(&mut self, p: [Vec3; 3], uv: [Vec2; 3], material: u16) {
        let base = self.positions.len() as u32;
        self.positions.extend(p);
        self.uvs.extend(uv);
        self.tris.push(([base, base + 1, base + 2], material));
    }

    fn quad(&mut self, p: [Vec3; 4], material: u16) {
        // uv: planar coordinates in metres along the quad's edges.
        let (a, b) = ((p[1] - p[0]).length(), (p[3] - p[0]).length());
        let uv = [Vec2::ZERO, Vec2::new(a, 0.0), Vec2::new(a, b), Vec2::new(0.0, b)];
        self.triangle([p[0], p[1], p[2]], [uv[0], uv[1], uv[2]], material);
        self.triangle([p[0], p[2], p[3]], [uv[0], uv[2], uv[3]], material);
    }

    /// Axis-aligned box.
    pub fn cuboid(&mut self, min: Vec3, max: Vec3, material: u16) {
        let c = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        let (f, t) = (false, true);
        self.quad([c(f, f, t), c(t, f, t), c(t, t, t), c(f, t, t)], material); // +z
        self.quad([c(t, f, f), c(f, f, f), c(f, t, f), c(t, t, f)], material); // -z
        self.quad([c(t, f, t), c(t, f, f), c(t, t, f), c(t, t, t)], material); // +x
        self.quad([c(f, f, f), c(f, f, t), c(f, t, t), c(f, t, f)], material); // -x
        self.quad([c(f, t, t), c(t, t, t), c(t, t, f), c(f, t, f)], material); // +y
        self.quad([c(f, f, f), c(t, f, f), c(t, f, t), c(f, f, t)], material); // -y
    }

    /// Vertical frustum (cylinder when the radii agree) standing on `base`, capped.
    pub fn frustum(
        &mut self,
        base: Vec3,
        r_bottom: f32,
        r_top: f32,
        height: f32,
        segments: u32,
        material: u16,
    ) {
        let ring = |r: f32, y: f32, i: u32| {
            let a = std::f32::consts::TAU * i as f32 / segments as f32;
            base + Vec3::new(r * a.cos(), y, r * a.sin())
        };
        for i in 0..segments {
            let (b0, b1) = (ring(r_bottom, 0.0, i), ring(r_bottom, 0.0, i + 1));
            let (t0, t1) = (ring(r_top, height, i), ring(r_top, height, i + 1));
            let u0 = i as f32 / segments as f32 * std::f32::consts::TAU * r_bottom.max(r_top);
            let u1 = (i + 1) as f32 / segments as f32 * std::f32::consts::TAU * r_bottom.max(r_top);
            let uv = [
                Vec2::new(u0, 0.0),
                Vec2::new(u1, 0.0),
                Vec2::new(u1, height),
                Vec2::new(u0, height),
            ];
            self.triangle([b0, t1, b1], [uv[0], uv[2], uv[1]], material);
            self.triangle([b0, t0, t1], [uv[0], uv[3], uv[2]], material);
            let top = base + Vec3::Y * height;
            let flat = |p: Vec3| Vec2::new(p.x, p.z);
            if r_top > 0.0 {
                self.triangle([top, t1, t0], [flat(top), flat(t1), flat(t0)], material);
            }
            if r_bottom > 0.0 {
                self.triangle([base, b0, b1], [flat(base), flat(b0), flat(b1)], material);
            }
        }
    }

    /// Ellipsoid with semi-axes `radii` around `center`.
    pub fn ellipsoid(
        &mut self,
        center: Vec3,
        radii: Vec3,
        rings: u32,
        segments: u32,
        material: u16,
    ) {
        let p = |i: u32, j: u32| {
            let th = std::f32::consts::PI * j as f32 / rings as f32;
            let ph = std::f32::consts::TAU * i as f32 / segments as f32;
            center + radii * Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin())
        };
        let uv = |i: u32, j: u32| {
            Vec2::new(i as f32 / segments as f32 * 3.0, j as f32 / rings as f32 * 1.5)
        };
        for i in 0..segments {
            for j in 0..rings {
                let (a, b, c, d) = (p(i, j), p(i + 1, j), p(i, j + 1), p(i + 1, j + 1));
                let (ua, ub, uc, ud) = (uv(i, j), uv(i + 1, j), uv(i, j + 1), uv(i + 1, j + 1));
                if j > 0 {
                    self.triangle([a, b, d], [ua, ub, ud], material);
                }
                if j + 1 < rings {
                    self.triangle([a, d, c], [ua, ud, uc], material);
                }
            }
        }
    }

    /// Merges vertices on a grid (vertex clustering) until at most `budget` non-degenerate
    /// triangles remain; corners keep their own uv. Cheap and good enough at the image
    /// sizes this renders.
    pub fn decimate(&mut self, budget: usize) {
        if self.tris.len() <= budget || self.positions.is_empty() {
            return;
        }
        let (lo, hi) = bounds(&self.positions);
        let extent = (hi - lo).max_element().max(1e-6);
        let mut cells = 256.0f32;
        loop {
            let cell = extent / cells;
            let key = |p: Vec3| {
                let q = ((p - lo) / cell).floor();
                (q.x as u64) | ((q.y as u64) << 21) | ((q.z as u64) << 42)
            };
            // Representative of a cell: the first vertex that falls in it (deterministic).
            let mut rep = std::collections::BTreeMap::new();
            let snapped: Vec<Vec3> =
                self.positions.iter().map(|&p| *rep.entry(key(p)).or_insert(p)).collect();
            let kept: Vec<([u32; 3], u16)> = self
                .tris
                .iter()
                .copied()
                .filter(|(c, _)| {
                    let [a, b, d] = c.map(|i| snapped[i as usize]);
                    (b - a).cross(d - a).length_squared() > 1e-14
                })
                .collect();
            if kept.len() <= budget || cells <= 4.0 {
                self.positions = snapped;
                self.tris = kept;
                return;
            }
            cells *= 0.75;
        }
    }

    /// Scales and shifts the mesh so that its bounds become `size` (x, y, z), centred on x/z
    /// with the base at y = 0.
    pub fn fit_to(&mut self, size: Vec3) {
        if self.positions.is_empty() {
            return;
        }
        let (lo, hi) = bounds(&self.positions);
        let extent = (hi - lo).max(Vec3::splat(1e-6));
        let scale = size / extent;
        let centre = Vec3::new(0.5 * (lo.x + hi.x), lo.y, 0.5 * (lo.z + hi.z));
        for p in &mut self.positions {
            *p = (*p - centre) * scale;
        }
    }

    /// Applies a linear map to every position (model rotation from the catalog).
    pub fn transform(&mut self, m: glam::Mat3) {
        for p in &mut self.positions {
            *p = m * *p;
        }
    }

    pub fn build(self) -> Mesh {
        let raw: Vec<Tri> = self
            .tris
            .iter()
            .map(|&(c, material)| {
                let [a, b, d] = c.map(|i| Vec3A::from(self.positions[i as usize]));
                let [ua, ub, ud] = c.map(|i| self.uvs[i as usize]);
                let (e1, e2) = (b - a, d - a);
                Tri {
                    v0: a,
                    e1,
                    e2,
                    normal: e1.cross(e2).normalize_or_zero(),
                    uv0: ua,
                    duv1: ub - ua,
                    duv2: ud - ua,
                    material,
                }
            })
            .filter(|t| t.normal != Vec3A::ZERO)
            .collect();
        let prims: Vec<obvhs::triangle::Triangle> = raw
            .iter()
            .map(|t| {
                let mut p = obvhs::triangle::Triangle::default();
                assign!(p.v0, t.v0);
                assign!(p.v1, t.v0 + t.e1);
                assign!(p.v2, t.v0 + t.e2);
                p
            })
            .collect();
        let (min, max) = if self.positions.is_empty() {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            bounds(&self.positions)
        };
        let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
            &prims,
            BvhBuildParams::medium_build(),
            &mut std::time::Duration::default(),
        );
        // Reorder triangles into BVH leaf order so traversal indexes them directly.
        let tris = bvh.primitive_indices.iter().map(|&i| raw[i as usize]).collect();
        Mesh { tris, bvh, materials: self.materials, min, max }
    }
}

fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points
        .iter()
        .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), &p| (lo.min(p), hi.max(p)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_hit_distance_normal_and_occlusion() {
        let mut b = MeshBuilder::default();
        let m = b.material(Material::flat(Vec3::ONE));
        b.cuboid(Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0), m);
        let mesh = b.build();
        let hit = mesh
            .closest(Vec3::new(0.0, 1.0, 5.0), Vec3::new(0.0, 0.0, -2.0), 0.0, f32::INFINITY)
            .unwrap();
        assert!((hit.t - 2.0).abs() < 1e-5, "{hit:?}");
        assert!((hit.normal - Vec3::Z).length() < 1e-5, "{hit:?}");
        assert!(mesh.occludes(Vec3::new(0.0, 1.0, 5.0), Vec3::NEG_Z, 0.0, 10.0));
        assert!(!mesh.occludes(Vec3::new(0.0, 1.0, 5.0), Vec3::NEG_Z, 0.0, 3.0));
        assert!(mesh.closest(Vec3::new(3.0, 1.0, 5.0), Vec3::NEG_Z, 0.0, f32::INFINITY).is_none());
    }

    #[test]
    fn decimation_respects_the_budget_and_fit_sets_the_size() {
        let mut b = MeshBuilder::default();
        let m = b.material(Material::flat(Vec3::ONE));
        b.ellipsoid(Vec3::ZERO, Vec3::ONE, 40, 80, m);
        let before = b.triangle_count();
        b.decimate(1000);
        assert!(
            b.triangle_count() <= 1000 && b.triangle_count() > 100,
            "{before} -> {}",
            b.triangle_count()
        );
        b.fit_to(Vec3::new(0.5, 1.0, 2.0));
        let mesh = b.build();
        assert!((mesh.max - mesh.min - Vec3::new(0.5, 1.0, 2.0)).abs().max_element() < 1e-4);
        assert!(mesh.min.y.abs() < 1e-5);
    }
}
