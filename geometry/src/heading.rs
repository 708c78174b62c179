//! Placing the views that registration could not link to the first photo, by their heading.
//! Registration places such a component by continuing the camera's motion
//! ([`crate::register`]), and what that gets wrong is almost only the heading: the turn about
//! the room's up axis (on val40 at 8 views, 53.8° median error about the up axis against
//! 4–5° of pitch and roll). Here each such component is turned, as one rigid body, about the
//! up axis of the cameras placed before it, through its first view's centre, to each of
//! [`HeadingParams::candidates`] headings; at each, those views' Gaussians are rendered
//! into the component's views at a low resolution and compared with their photos and with
//! the network's own depth of those views ([`HeadingParams::score`]). The best-scoring
//! heading that shows enough of them ([`HeadingParams::min_coverage`]) replaces
//! the continued one when it scores better than it by [`HeadingParams::max_error_ratio`];
//! else the continued pose stays. The components are placed in the photos' order, each
//! against the views placed before it, so a component next to an earlier one is matched
//! against it too. The defaults were chosen on val40 and 120 more val scenes at 8 views
//! (the model card's history, "Unlinked views turned to their best heading").

use glam::{Quat, Vec3};
use inssplat_proto::{Camera, GaussianScene};
use rayon::prelude::*;

use crate::target_pose::downsample;
use inssplat_raster::masks::{MASK_ALPHA, MaskError, colours, splats};
use inssplat_raster::render::{Splats, render};

/// Tunables of [`place_by_heading`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingParams {
    /// Headings tried, evenly spaced over the full turn (the continued one is the first).
    pub candidates: usize,
    /// The views are compared at their size divided by this.
    pub factor: usize,
    /// A new heading counts only where the render covers at least this share of the
    /// component's pixels.
    pub min_coverage: f32,
    /// The best new heading replaces the continued one when its score is under this share
    /// of the continued one's.
    pub max_error_ratio: f32,
    /// What an uncovered pixel costs in a heading's score, as a squared colour error: lower
    /// trusts a close match of a small overlap more (0.1 scored lower than 0.05 and 0.02).
    pub uncovered_cost: f32,
    /// Weight of the depth disagreement (mean |ln| of rendered over predicted depth) beside
    /// the squared colour error.
    pub depth_weight: f32,
}

impl HeadingParams {
    /// A heading's score, lower is better: the covered pixels' colour and depth error and the
    /// uncovered ones' fixed cost, per pixel (infinite when nothing is covered).
    pub fn score(&self, fit: &Fit) -> f64 {
        if !fit.error.is_finite() {
            return f64::INFINITY;
        }
        let c = f64::from(fit.coverage);
        c * (fit.error + f64::from(self.depth_weight) * fit.depth_error)
            + (1.0 - c) * f64::from(self.uncovered_cost)
    }
}

impl Default for HeadingParams {
    fn default() -> Self {
        Self {
            candidates: 36,
            factor: 4,
            min_coverage: 0.25,
            max_error_ratio: 0.9,
            uncovered_cost: 0.05,
            depth_weight: 0.05,
        }
    }
}

/// What [`place_by_heading`] did with one component.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingChoice {
    /// The component's first view (registration's root).
    pub root: usize,
    /// The turn applied about the up axis, degrees (0 when the continued pose stays).
    pub turn_deg: f32,
    /// How the continued heading fits, and the best new one (the continued one's again
    /// when no new heading covers enough).
    pub continued: Fit,
    pub best: Fit,
}

/// How a render matches the photos at one heading.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Fit {
    /// Mean squared colour error over the covered pixels (infinite when none is covered).
    pub error: f64,
    /// Share of the pixels the render covers (alpha above [`MASK_ALPHA`]).
    pub coverage: f32,
    /// Mean |ln(rendered depth / the view's own depth)| over the covered pixels.
    pub depth_error: f64,
}

/// Turns every component other than view 0's (`component[v]` is view v's root, as
/// [`crate::register::Registration::component`]), in the photos' order, to the heading at
/// which the Gaussians of the views placed so far (view 0's component, then each component
/// as it is placed) match its `photos` (planar `[3][H][W]` in 0..1, one per view, each its
/// camera's size) and the network's `depths` of them (`[H][W]`) best. `gaussians(cameras,
/// views)` gives the Gaussians of `views` placed with `cameras`. Returns one choice per such
/// component.
pub fn place_by_heading(
    cameras: &mut [Camera],
    component: &[usize],
    photos: &[&[f32]],
    depths: &[&[f32]],
    params: &HeadingParams,
    gaussians: &dyn Fn(&[Camera], &[usize]) -> GaussianScene,
) -> Result<Vec<HeadingChoice>, MaskError> {
    let roots: Vec<usize> = (1..cameras.len()).filter(|&v| component[v] == v).collect();
    if roots.is_empty() {
        return Ok(Vec::new());
    }
    let mut placed: Vec<usize> = (0..cameras.len()).filter(|&v| component[v] == 0).collect();
    // A placed view's camera no longer moves, so its Gaussians are made once.
    let mut linked = gaussians(cameras, &placed);
    let mut choices = Vec::new();
    for (i, &root) in roots.iter().enumerate() {
        let members: Vec<usize> = (0..cameras.len()).filter(|&v| component[v] == root).collect();
        linked.validate()?;
        let reference: Vec<&Camera> = placed.iter().map(|&v| &cameras[v]).collect();
        let Some(up) = up_axis(&reference).filter(|_| !linked.is_empty()) else { break };
        choices.push(place_component(&linked, cameras, &members, up, photos, depths, params)?);
        if i + 1 < roots.len() {
            linked.append(gaussians(cameras, &members));
        }
        placed.extend(members);
    }
    Ok(choices)
}

/// Turns the component of `members` (its root first) about `up` to its best heading against
/// `linked`, when that heading wins (see the module documentation).
fn place_component(
    linked: &GaussianScene,
    cameras: &mut [Camera],
    members: &[usize],
    up: Vec3,
    photos: &[&[f32]],
    depths: &[&[f32]],
    params: &HeadingParams,
) -> Result<HeadingChoice, MaskError> {
    let colours = colours(linked);
    let splats = splats(linked, &colours, 3);
    let root = members[0];
    let small: Vec<(Camera, Vec<f32>, Vec<f32>)> = members
        .iter()
        .map(|&v| {
            let k = cameras[v].intrinsics;
            let (w, h) = (k.width as usize / params.factor, k.height as usize / params.factor);
            let cam = Camera { intrinsics: k.scaled_to(w as u32, h as u32), ..cameras[v] };
            (
                cam,
                downsample(photos[v], w, h, params.factor),
                downsample(depths[v], w, h, params.factor),
            )
        })
        .collect();
    let pivot = cameras[root].center();
    let angle_of = |k: usize| k as f32 * std::f32::consts::TAU / params.candidates as f32;
    let fits: Vec<Fit> = (0..params.candidates)
        .into_par_iter()
        .map(|k| fit(&splats, &small, up, pivot, angle_of(k)))
        .collect::<Result<_, _>>()?;
    let continued = fits[0];
    let (best_k, best) = fits
        .iter()
        .enumerate()
        .skip(1)
        .filter(|(_, f)| f.coverage >= params.min_coverage)
        .min_by(|a, b| params.score(a.1).total_cmp(&params.score(b.1)))
        .map_or((0, continued), |(k, f)| (k, *f));
    let wins = best_k != 0
        && params.score(&best).is_finite()
        && params.score(&best) < f64::from(params.max_error_ratio) * params.score(&continued);
    let angle = if wins { angle_of(best_k) } else { 0.0 };
    if wins {
        for &v in members {
            cameras[v] = turned(&cameras[v], up, pivot, angle);
        }
    }
    let turn = angle.to_degrees();
    Ok(HeadingChoice {
        root,
        turn_deg: if turn > 180.0 { turn - 360.0 } else { turn },
        continued,
        best,
    })
}

/// The world's up direction as the linked cameras see it: the direction most nearly at right
/// angles to all their image rows (a level camera's x axis is horizontal), drawn towards the
/// mean of their images' up axes (−y of the camera frame), which alone decides it for a single
/// camera or cameras that all face one way; `None` without cameras.
fn up_axis(cameras: &[&Camera]) -> Option<Vec3> {
    let mean_up: Vec3 = cameras.iter().map(|c| c.rotation.conjugate() * Vec3::NEG_Y).sum();
    if mean_up.length() < 1e-6 {
        return None;
    }
    let prior = mean_up.normalize();
    // M = Σ x xᵀ + PRIOR (I − p pᵀ); its eigenvector of least eigenvalue, by power iteration
    // on trace(M)·I − M from the prior.
    const PRIOR: f32 = 0.01;
    let rows: Vec<Vec3> = cameras.iter().map(|c| c.rotation.conjugate() * Vec3::X).collect();
    let apply = |u: Vec3| -> Vec3 {
        rows.iter().map(|x| *x * x.dot(u)).sum::<Vec3>() + PRIOR * (u - prior * prior.dot(u))
    };
    let trace = rows.iter().map(|x| x.length_squared()).sum::<f32>() + 2.0 * PRIOR;
    let mut u = prior;
    for _ in 0..100 {
        u = (trace * u - apply(u)).normalize();
    }
    Some(if u.dot(prior) < 0.0 { -u } else { u })
}

/// `camera` turned by `angle` (radians) about `up` through `pivot`, as a rigid motion of the
/// camera in the world.
fn turned(camera: &Camera, up: Vec3, pivot: Vec3, angle: f32) -> Camera {
    let turn = Quat::from_axis_angle(up, angle);
    let centre = pivot + turn * (camera.center() - pivot);
    let rotation = (camera.rotation * turn.conjugate()).normalize();
    Camera { rotation, translation: -(rotation * centre), ..*camera }
}

/// The mean squared colour error and depth disagreement over the pixels the render covers
/// (alpha above [`MASK_ALPHA`]) of the component's `views` turned by `angle`, and the covered
/// share.
fn fit(
    splats: &Splats<'_>,
    views: &[(Camera, Vec<f32>, Vec<f32>)],
    up: Vec3,
    pivot: Vec3,
    angle: f32,
) -> Result<Fit, MaskError> {
    let (mut error, mut covered, mut pixels, mut depth_error) = (0.0f64, 0usize, 0usize, 0.0f64);
    for (camera, photo, depth) in views {
        let (image, _) = render(splats, &turned(camera, up, pivot, angle), &[0.0; 3])?;
        let n = image.alpha.len();
        pixels += n;
        for (p, &a) in image.alpha.iter().enumerate() {
            if a > MASK_ALPHA {
                covered += 1;
                depth_error +=
                    f64::from((image.depth[p].max(1e-6) / depth[p].max(1e-6)).ln().abs());
                // Compared un-premultiplied, so that a half-covered pixel is not judged dark.
                error += (0..3)
                    .map(|c| f64::from(image.features[c * n + p] / a - photo[c * n + p]).powi(2))
                    .sum::<f64>();
            }
        }
    }
    Ok(match covered {
        0 => Fit { error: f64::INFINITY, coverage: 0.0, depth_error: f64::INFINITY },
        _ => Fit {
            error: error / (3 * covered) as f64,
            coverage: covered as f32 / pixels as f32,
            depth_error: depth_error / covered as f64,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use inssplat_proto::Intrinsics;

    #[test]
    fn the_up_axis_is_square_to_the_cameras_rows_and_a_lone_camera_gives_its_own() {
        let k = Intrinsics::from_fov_y(32, 32, 1.0);
        // Cameras looking 30° down from four headings: their mean image-up leans, their rows
        // are level.
        let cams: Vec<Camera> = (0..4)
            .map(|i| {
                let a = 0.4 + i as f32 * 0.7;
                let eye = Vec3::new(a.cos(), 1.0, a.sin());
                let ahead = eye + Vec3::new(-a.sin(), -(30f32.to_radians().tan()), a.cos());
                Camera::look_at(k, eye, ahead, Vec3::Y)
            })
            .collect();
        let up = up_axis(&cams.iter().collect::<Vec<_>>()).unwrap();
        assert!(up.angle_between(Vec3::Y).to_degrees() < 0.5, "{up}");
        let lone = up_axis(&[&cams[0]]).unwrap();
        let own = cams[0].rotation.conjugate() * Vec3::NEG_Y;
        assert!(lone.angle_between(own).to_degrees() < 0.5, "{lone} vs {own}");
        assert!(up_axis(&[]).is_none());
    }

    #[test]
    fn a_turn_moves_the_camera_about_the_pivot_and_turns_its_view_alike() {
        let k = Intrinsics::from_fov_y(32, 32, 1.0);
        let cam = Camera::look_at(k, Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, -1.0), Vec3::Y);
        let t = turned(&cam, Vec3::Y, Vec3::ZERO, std::f32::consts::FRAC_PI_2);
        // A quarter turn about +y takes x to −z, and the view direction −z to −x.
        assert!(t.center().distance(Vec3::new(0.0, 0.0, -1.0)) < 1e-5, "{}", t.center());
        let ahead = t.rotation.conjugate() * Vec3::Z;
        assert!(ahead.distance(Vec3::NEG_X) < 1e-5, "{ahead}");
    }
}
