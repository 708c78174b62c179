//! Stage "register": the views' cameras. Known poses are taken as given; else the camera
//! head's, registered from matched keypoints (found in each photo's own detail where it is
//! larger than the network's input: XFeat + LighterGlue, [`crate::matcher`], or FAST + BRIEF)
//! and lifted by the predicted depth ([`inssplat_geometry::register`]).

use glam::{Quat, Vec2, Vec3};
use image::RgbImage;
use inssplat_geometry::register::{
    KeypointImage, PairMatches, RegisterParams, RegisterView, brief_matches, register,
};
use inssplat_proto::api::{CameraFit, FocalSource, Placement};
use inssplat_proto::signature::CAMERA_CHANNELS;
use inssplat_proto::{Camera, Intrinsics};

use super::decode::ModelImage;
use super::{Stopwatch, plane};
use crate::backend::{ModelOutput, RuntimeError};
use crate::matcher::{LearnedMatcher, ViewPhoto};
use crate::reconstruct::PipelineError;

/// The views' cameras and how each was found.
pub struct Cameras {
    pub cameras: Vec<Camera>,
    pub placements: Vec<Placement>,
    /// Where each view's focal length came from.
    pub focal: Vec<FocalSource>,
    /// Registration's component root of every view
    /// ([`inssplat_geometry::register::Registration::component`]);
    /// `None` when registration did not run.
    pub component: Option<Vec<usize>>,
    /// Registration's fit of each view, in model pixels (`None` where it did not run).
    pub fit: Option<Vec<CameraFit>>,
}

/// Cameras predicted by the network (model resolution, world = view 0's camera).
pub fn predicted_cameras(out: &ModelOutput) -> Vec<Camera> {
    out.camera
        .chunks_exact(CAMERA_CHANNELS)
        .map(|c| {
            let q = Quat::from_xyzw(c[4], c[5], c[6], c[3]);
            let rotation =
                if q.is_finite() && q.length() > 1e-8 { q.normalize() } else { Quat::IDENTITY };
            let focal =
                |fov: f32, size: usize| 0.5 * size as f32 / (0.5 * fov.clamp(0.05, 3.0)).tan();
            // A network trained on squares gives both fields of view alike; on an oblong input
            // the long side's is the one it reads as in the square (the photo's long side is
            // the square's side either way), and the pixels are square.
            let (fx, fy) = match out.width.cmp(&out.height) {
                std::cmp::Ordering::Equal => (focal(c[8], out.width), focal(c[7], out.height)),
                std::cmp::Ordering::Greater => (focal(c[8], out.width), focal(c[8], out.width)),
                std::cmp::Ordering::Less => (focal(c[7], out.height), focal(c[7], out.height)),
            };
            let intrinsics = Intrinsics {
                fx,
                fy,
                cx: 0.5 * out.width as f32,
                cy: 0.5 * out.height as f32,
                width: out.width as u32,
                height: out.height as u32,
            };
            Camera { intrinsics, rotation, translation: Vec3::new(c[0], c[1], c[2]) }
        })
        .collect()
}

/// The cameras predicted by the network, each view's focal length replaced by its photo's
/// EXIF where it has one; with where each came from.
fn with_exif(mut cameras: Vec<Camera>, decoded: &[ModelImage]) -> (Vec<Camera>, Vec<FocalSource>) {
    let sources = cameras
        .iter_mut()
        .zip(decoded)
        .map(|(cam, d)| match d.exif_focal {
            Some(f) => {
                let model_px = f * d.letterbox.scale;
                (cam.intrinsics.fx, cam.intrinsics.fy) = (model_px, model_px);
                FocalSource::Exif
            }
            None => FocalSource::CameraHead,
        })
        .collect();
    (cameras, sources)
}

/// How registration placed view `v`, given the root of its component.
fn placement(v: usize, root: usize) -> Placement {
    match (v, root) {
        (0, _) => Placement::Reference,
        (_, 0) => Placement::Registered,
        (_, 1) => Placement::CameraHead,
        _ => Placement::Continued,
    }
}

/// The cameras: `known` as given, else the camera head's, registered with `params` (timed as
/// stage "register") on the matches of `matcher` (FAST + BRIEF without one) unless `params`
/// is `None`.
pub fn run(
    clock: &mut Stopwatch<'_>,
    out: &ModelOutput,
    decoded: &[ModelImage],
    known: Option<&[Camera]>,
    params: Option<&RegisterParams>,
    matcher: Option<&LearnedMatcher>,
) -> Result<Cameras, PipelineError> {
    let params = match (known, params) {
        (Some(poses), _) => return given(poses, decoded.len()),
        (None, None) => {
            let (predicted, focal) = with_exif(predicted_cameras(out), decoded);
            return Ok(camera_head(predicted, focal));
        }
        (None, Some(params)) => params,
    };
    // A focal length from EXIF is the photo's own: the one measured from the matches, shared by
    // every view, is not sought when any view has one.
    let (predicted, exif) = with_exif(predicted_cameras(out), decoded);
    let any_exif = exif.contains(&FocalSource::Exif);
    clock.time("register", || -> Result<Cameras, PipelineError> {
        let pixels = out.height * out.width;
        let details: Vec<Option<KeypointImage>> = match matcher {
            Some(_) => vec![None; decoded.len()],
            None => decoded
                .iter()
                .map(|d| {
                    d.detail_in_model().map(|(rgb, per_view, [x, y])| {
                        KeypointImage::of_photo(rgb, per_view, Vec2::new(x, y))
                    })
                })
                .collect(),
        };
        let views: Vec<RegisterView<'_>> = (0..out.views)
            .map(|v| RegisterView {
                rgb: &decoded[v].planar,
                depth: &out.depth[plane(1, pixels, v)],
                photo: decoded[v].letterbox.photo_rect(),
                camera: &predicted[v],
                detail: details[v].as_ref(),
            })
            .collect();
        let (matches, keypoints) = match matcher {
            Some(matcher) => learned_matches(matcher, decoded)?,
            None => brief_matches(&views, params),
        };
        let params = &RegisterParams {
            min_inliers: matcher.map_or(params.min_inliers, |m| m.params.min_inliers),
            estimate_focal: params.estimate_focal && !any_exif,
            ..params.clone()
        };
        let registration = register(&views, &matches, params);
        let placements = registration
            .component
            .iter()
            .enumerate()
            .map(|(v, &root)| placement(v, root))
            .collect();
        let focal = match registration.focal_scale {
            Some(_) => vec![FocalSource::Measured; exif.len()],
            None => exif,
        };
        Ok(Cameras {
            cameras: registration.cameras,
            placements,
            focal,
            component: Some(registration.component),
            fit: Some(
                registration
                    .fit
                    .iter()
                    .zip(keypoints)
                    .map(|(f, keypoints)| CameraFit {
                        keypoints,
                        matches: f.matches,
                        reprojection_px: f.reprojection_px,
                    })
                    .collect(),
            ),
        })
    })
}

/// XFeat + LighterGlue matches of every pair of views, found in each photo's detail where it
/// has one, else in its part of the model's input.
fn learned_matches(
    matcher: &LearnedMatcher,
    decoded: &[ModelImage],
) -> Result<(Vec<PairMatches>, Vec<usize>), RuntimeError> {
    let own: Vec<Option<RgbImage>> =
        decoded.iter().map(|d| d.detail.is_none().then(|| photo_of_input(d))).collect();
    let photos: Vec<ViewPhoto<'_>> = decoded
        .iter()
        .zip(&own)
        .map(|(d, own)| match (d.detail_in_model(), own) {
            (Some((rgb, per_view, [x, y])), _) => {
                ViewPhoto { rgb, per_view, origin: Vec2::new(x, y) }
            }
            (None, Some(rgb)) => {
                let [x0, y0, _, _] = d.letterbox.photo_rect();
                ViewPhoto { rgb, per_view: 1.0, origin: Vec2::new(x0 as f32, y0 as f32) }
            }
            (None, None) => unreachable!("a view without a detail has its own photo"),
        })
        .collect();
    matcher.pair_matches(&photos)
}

/// The photo's rectangle of a view's planar input, 8-bit.
fn photo_of_input(d: &ModelImage) -> RgbImage {
    let [x0, y0, x1, y1] = d.letterbox.photo_rect();
    let [iw, ih] = d.letterbox.input;
    let px = (iw * ih) as usize;
    let (w, h) = (x1.saturating_sub(x0).max(1), y1.saturating_sub(y0).max(1));
    RgbImage::from_fn(w, h, |x, y| {
        let i = ((y0 + y).min(ih - 1) * iw + (x0 + x).min(iw - 1)) as usize;
        image::Rgb(
            [0, 1, 2].map(|c| (d.planar[c * px + i] * 255.0).round().clamp(0.0, 255.0) as u8),
        )
    })
}

fn given(poses: &[Camera], views: usize) -> Result<Cameras, PipelineError> {
    if poses.len() != views {
        return Err(PipelineError::Poses { given: poses.len(), views });
    }
    Ok(Cameras {
        cameras: poses.to_vec(),
        placements: vec![Placement::Given; poses.len()],
        focal: vec![FocalSource::Given; poses.len()],
        component: None,
        fit: None,
    })
}

fn camera_head(predicted: Vec<Camera>, focal: Vec<FocalSource>) -> Cameras {
    let placements = (0..predicted.len())
        .map(|v| if v == 0 { Placement::Reference } else { Placement::CameraHead })
        .collect();
    Cameras { cameras: predicted, placements, focal, component: None, fit: None }
}
