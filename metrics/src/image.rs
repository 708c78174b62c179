//! Image and depth metrics. PSNR and SSIM take planar images `[C][H][W]` with values in
//! [0, 1] (data range 1). SSIM is the standard one of Wang et al.: an 11×11 Gaussian window
//! with σ = 1.5, C1 = (0.01)², C2 = (0.03)², statistics over the 'valid' window positions,
//! averaged over positions and channels. Depth AbsRel aligns the prediction's scale first:
//! s = median(gt) / median(pred) over pixels where both are positive and finite, then
//! AbsRel = mean |s·pred − gt| / gt over those pixels.

use super::{MetricError, same_len};

pub const SSIM_WINDOW: usize = 11;
pub const SSIM_SIGMA: f64 = 1.5;

/// PSNR in dB for data range 1 (+∞ for identical images).
pub fn psnr(pred: &[f32], gt: &[f32]) -> Result<f64, MetricError> {
    same_len("images", pred.len(), gt.len())?;
    let mse =
        pred.iter().zip(gt).map(|(a, b)| (f64::from(*a) - f64::from(*b)).powi(2)).sum::<f64>()
            / pred.len().max(1) as f64;
    Ok(-10.0 * mse.log10())
}

/// Mean SSIM of two planar images of `channels` × `height` × `width`.
pub fn ssim(
    pred: &[f32],
    gt: &[f32],
    channels: usize,
    width: usize,
    height: usize,
) -> Result<f64, MetricError> {
    same_len("images", pred.len(), gt.len())?;
    let expected = channels * width * height;
    if pred.len() != expected {
        return Err(MetricError::Shape {
            what: "SSIM image",
            width,
            height,
            channels,
            expected,
            actual: pred.len(),
        });
    }
    if width < SSIM_WINDOW || height < SSIM_WINDOW {
        return Err(MetricError::TooSmall { width, height });
    }
    let window = gaussian_window();
    let plane = width * height;
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    for c in 0..channels {
        let x: Vec<f64> = pred[c * plane..(c + 1) * plane].iter().map(|&v| f64::from(v)).collect();
        let y: Vec<f64> = gt[c * plane..(c + 1) * plane].iter().map(|&v| f64::from(v)).collect();
        let filt = |f: &dyn Fn(usize) -> f64| {
            filter_valid(&(0..plane).map(f).collect::<Vec<_>>(), width, height, &window)
        };
        let (mx, my) = (filt(&|i| x[i]), filt(&|i| y[i]));
        let (xx, yy, xy) = (filt(&|i| x[i] * x[i]), filt(&|i| y[i] * y[i]), filt(&|i| x[i] * y[i]));
        let mut sum = 0.0;
        for i in 0..mx.len() {
            let (vx, vy, cxy) =
                (xx[i] - mx[i] * mx[i], yy[i] - my[i] * my[i], xy[i] - mx[i] * my[i]);
            sum += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2))
                / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
        }
        total += sum / mx.len() as f64;
    }
    Ok(total / channels as f64)
}

/// Normalized 1D Gaussian of [`SSIM_WINDOW`] taps, σ = [`SSIM_SIGMA`].
fn gaussian_window() -> Vec<f64> {
    let half = (SSIM_WINDOW / 2) as f64;
    let w: Vec<f64> = (0..SSIM_WINDOW)
        .map(|i| (-((i as f64 - half).powi(2)) / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.into_iter().map(|v| v / s).collect()
}

/// Separable 2D filtering keeping only positions where the window fits:
/// `(height − 10) × (width − 10)` values.
fn filter_valid(img: &[f64], width: usize, height: usize, w: &[f64]) -> Vec<f64> {
    let k = w.len();
    let (ow, oh) = (width - k + 1, height - k + 1);
    let mut rows = vec![0.0; ow * height];
    for y in 0..height {
        for x in 0..ow {
            rows[y * ow + x] = (0..k).map(|t| w[t] * img[y * width + x + t]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..k).map(|t| w[t] * rows[(y + t) * ow + x]).sum();
        }
    }
    out
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthScores {
    pub abs_rel: f64,
    /// The median scale applied to the prediction.
    pub scale: f64,
    pub pixels: usize,
}

/// Depth AbsRel after median scale alignment; `None` without a pixel valid on both sides.
pub fn depth_abs_rel(pred: &[f32], gt: &[f32]) -> Result<Option<DepthScores>, MetricError> {
    same_len("depth maps", pred.len(), gt.len())?;
    let pairs: Vec<(f64, f64)> = valid_depth_pairs(pred, gt, |_| true).collect();
    if pairs.is_empty() {
        return Ok(None);
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
    };
    let scale =
        median(pairs.iter().map(|p| p.1).collect()) / median(pairs.iter().map(|p| p.0).collect());
    let pixels = pairs.len();
    let abs_rel = mean_abs_rel(pairs.into_iter(), scale).expect("pairs are not empty");
    Ok(Some(DepthScores { abs_rel, scale, pixels }))
}

/// AbsRel of `scale`·`pred` over the pixels valid on both sides where `keep` is true (a part of
/// the image, scored at the scale [`depth_abs_rel`] found for the whole); `None` without one.
pub fn depth_abs_rel_where(
    pred: &[f32],
    gt: &[f32],
    scale: f64,
    keep: &[bool],
) -> Result<Option<f64>, MetricError> {
    same_len("depth maps", pred.len(), gt.len())?;
    same_len("pixel selection", gt.len(), keep.len())?;
    Ok(mean_abs_rel(valid_depth_pairs(pred, gt, |i| keep[i]), scale))
}

/// (prediction, truth) of the pixels `keep` selects where both are finite and positive.
fn valid_depth_pairs<'a>(
    pred: &'a [f32],
    gt: &'a [f32],
    keep: impl Fn(usize) -> bool + 'a,
) -> impl Iterator<Item = (f64, f64)> + 'a {
    let ok = |v: f32| v.is_finite() && v > 0.0;
    pred.iter()
        .zip(gt)
        .enumerate()
        .filter(move |&(i, (p, g))| ok(*p) && ok(*g) && keep(i))
        .map(|(_, (p, g))| (f64::from(*p), f64::from(*g)))
}

fn mean_abs_rel(pairs: impl Iterator<Item = (f64, f64)>, scale: f64) -> Option<f64> {
    let (sum, n) =
        pairs.fold((0.0, 0usize), |(sum, n), (p, g)| (sum + (scale * p - g).abs() / g, n + 1));
    (n > 0).then(|| sum / n as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_by_hand() {
        // MSE = (0.1² + 0.1²) / 4 = 0.005 → 10·log10(200).
        let p = psnr(&[0.1, 0.5, 0.5, 0.0], &[0.0, 0.5, 0.6, 0.0]).unwrap();
        assert!((p - 10.0 * 200f64.log10()).abs() < 1e-4, "{p}");
        assert_eq!(psnr(&[0.3], &[0.3]).unwrap(), f64::INFINITY);
    }

    /// Direct 2D SSIM at every valid position, no separable filtering: the oracle.
    fn ssim_direct(x: &[f32], y: &[f32], w: usize, h: usize) -> f64 {
        let g = gaussian_window();
        let (c1, c2) = (1e-4, 9e-4);
        let mut sum = 0.0;
        for oy in 0..=h - 11 {
            for ox in 0..=w - 11 {
                let (mut mx, mut my, mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for ty in 0..11 {
                    for tx in 0..11 {
                        let wt = g[ty] * g[tx];
                        let (a, b) = (
                            f64::from(x[(oy + ty) * w + ox + tx]),
                            f64::from(y[(oy + ty) * w + ox + tx]),
                        );
                        (mx, my, xx, yy, xy) = (
                            mx + wt * a,
                            my + wt * b,
                            xx + wt * a * a,
                            yy + wt * b * b,
                            xy + wt * a * b,
                        );
                    }
                }
                let (vx, vy, cxy) = (xx - mx * mx, yy - my * my, xy - mx * my);
                sum += ((2.0 * mx * my + c1) * (2.0 * cxy + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
        sum / ((w - 10) * (h - 10)) as f64
    }

    #[test]
    fn ssim_known_answers() {
        let (w, h) = (16, 13);
        let x: Vec<f32> = (0..w * h).map(|i| ((i * 37 % 101) as f32) / 100.0).collect();
        assert!((ssim(&x, &x, 1, w, h).unwrap() - 1.0).abs() < 1e-9);
        // Constant images a and b: only the luminance term remains, (2ab + C1)/(a² + b² + C1).
        let (a, b) = (0.2f32, 0.6f32);
        let s = ssim(&vec![a; 2 * w * h], &vec![b; 2 * w * h], 2, w, h).unwrap();
        let (a, b) = (f64::from(a), f64::from(b));
        assert!((s - (2.0 * a * b + 1e-4) / (a * a + b * b + 1e-4)).abs() < 1e-6, "{s}");
        // A noisy, contrast-changed copy agrees with the direct 2D computation.
        let y: Vec<f32> = x
            .iter()
            .enumerate()
            .map(|(i, v)| 0.5 * v + 0.1 * ((i * 13 % 7) as f32) / 7.0)
            .collect();
        let s = ssim(&x, &y, 1, w, h).unwrap();
        assert!((s - ssim_direct(&x, &y, w, h)).abs() < 1e-9, "{s}");
        assert!(s < 0.95);
        assert_eq!(
            ssim(&x[..100], &x[..100], 1, 10, 10).unwrap_err(),
            MetricError::TooSmall { width: 10, height: 10 }
        );
    }

    #[test]
    fn abs_rel_after_median_scale() {
        // The prediction is half the truth except one pixel 4× too far, and the last pixel has
        // no truth: the median scale is 3 / 1.5 = 2, every error is 0 but |2·10 − 5|/5 = 3.
        let gt = [1.0, 2.0, 3.0, 4.0, 5.0, 0.0];
        let pred = [0.5, 1.0, 1.5, 2.0, 10.0, 7.0];
        let d = depth_abs_rel(&pred, &gt).unwrap().unwrap();
        assert_eq!((d.scale, d.pixels), (2.0, 5));
        assert!((d.abs_rel - 3.0 / 5.0).abs() < 1e-12, "{d:?}");
        assert_eq!(depth_abs_rel(&[1.0], &[0.0]).unwrap(), None);
        // The same scale on a part: the far pixel alone, then the rest.
        let far = [false, false, false, false, true, true];
        assert_eq!(depth_abs_rel_where(&pred, &gt, d.scale, &far).unwrap(), Some(3.0));
        let rest = far.map(|f| !f);
        assert_eq!(depth_abs_rel_where(&pred, &gt, d.scale, &rest).unwrap(), Some(0.0));
        assert_eq!(depth_abs_rel_where(&pred, &gt, d.scale, &[false; 6]).unwrap(), None);
        assert!(depth_abs_rel_where(&pred, &gt, d.scale, &[true; 5]).is_err());
    }
}
