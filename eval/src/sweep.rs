//! `inssplat-eval score --sweep`: every knob of the pipeline that trades speed for accuracy (views,
//! voxel size, clustering subsample) run through the evaluation, and a speed–accuracy chart
//! (PNG and SVG): median seconds per scene against instance mIoU and against PSNR, one point
//! per configuration, the Pareto front (no other point both faster and better) joined by a line.
//! The network resolution is fixed by the model file, so a sweep over resolutions is a sweep
//! over model files; rendering runs on the CPU (the pipeline has no wgpu path yet).

use std::path::Path;

use anyhow::Context;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use serde::Serialize;

/// One configuration of the sweep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Knobs {
    pub views: usize,
    /// Voxel edge as a fraction of the scene extent.
    pub voxel_fraction: f32,
    /// Points HDBSCAN sees.
    pub cluster_samples: usize,
}

impl Knobs {
    pub fn label(&self) -> String {
        format!("{}v vox1/{:.0} hdb{}", self.views, 1.0 / self.voxel_fraction, self.cluster_samples)
    }
}

/// The grid a sweep runs: every view count asked × 3 voxel sizes × 2 subsample sizes.
pub fn grid(views: &[usize]) -> Vec<Knobs> {
    let mut out = Vec::new();
    for &v in views {
        for voxel_fraction in [1.0 / 120.0, 1.0 / 60.0, 1.0 / 30.0] {
            for cluster_samples in [1000, 4000] {
                out.push(Knobs { views: v, voxel_fraction, cluster_samples });
            }
        }
    }
    out
}

/// A measured configuration.
#[derive(Debug, Clone, Serialize)]
pub struct SweepPoint {
    pub knobs: Knobs,
    pub seconds: f64,
    pub instance_miou: Option<f64>,
    pub psnr: Option<f64>,
    /// On the Pareto front of time vs instance mIoU.
    pub pareto_instance: bool,
    pub pareto_psnr: bool,
}

/// Marks the points that no other point beats on both time (lower) and score (higher).
pub fn mark_pareto(points: &mut [SweepPoint]) {
    let front = |points: &[SweepPoint], score: fn(&SweepPoint) -> Option<f64>| -> Vec<bool> {
        points
            .iter()
            .map(|p| {
                score(p).is_some_and(|sp| {
                    !points.iter().any(|q| {
                        score(q).is_some_and(|sq| {
                            q.seconds <= p.seconds && sq >= sp && (q.seconds < p.seconds || sq > sp)
                        })
                    })
                })
            })
            .collect()
    };
    let a = front(points, |p| p.instance_miou);
    let b = front(points, |p| p.psnr);
    for (p, (a, b)) in points.iter_mut().zip(a.into_iter().zip(b)) {
        p.pareto_instance = a;
        p.pareto_psnr = b;
    }
}

/// Point colours, one per view count (one per run in [`crate::curve`]).
pub(crate) const VIEW_COLOURS: [RGBColor; 5] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
];

pub(crate) fn register_font() -> bool {
    const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *REGISTERED.get_or_init(|| match std::fs::read(FONT) {
        Ok(bytes) => plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            Box::leak(bytes.into_boxed_slice()),
        )
        .is_ok(),
        Err(_) => false,
    })
}

/// A chart panel's axes: x from 0 to `x_end`, y over the scores' range padded by a tenth; the
/// title and x axis's name where `text` can be drawn.
pub(crate) struct Axes<'t> {
    pub title: &'t str,
    pub x_desc: &'t str,
    pub x_end: f64,
}

impl Axes<'_> {
    /// The panel on `area` for scores from `lo` to `hi`, its mesh drawn.
    pub(crate) fn frame<'a, DB: DrawingBackend>(
        &self,
        area: &'a DrawingArea<DB, Shift>,
        (lo, hi): (f64, f64),
        text: bool,
    ) -> anyhow::Result<ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>>
    where
        DB::ErrorType: 'static,
    {
        let pad = ((hi - lo) * 0.1).max(1e-3);
        let mut builder = ChartBuilder::on(area);
        builder.margin(12);
        if text {
            builder
                .caption(self.title, ("sans-serif", 18))
                .x_label_area_size(36)
                .y_label_area_size(50);
        }
        let mut chart = builder
            .build_cartesian_2d(0.0..self.x_end, (lo - pad)..(hi + pad))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if text {
            chart
                .configure_mesh()
                .x_desc(self.x_desc)
                .draw()
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(chart)
    }
}

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    points: &[SweepPoint],
    title: &str,
    score: fn(&SweepPoint) -> Option<f64>,
    on_front: fn(&SweepPoint) -> bool,
    text: bool,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let scored: Vec<(f64, f64, &SweepPoint)> =
        points.iter().filter_map(|p| score(p).map(|s| (p.seconds, s, p))).collect();
    if scored.is_empty() {
        return Ok(());
    }
    let (x_max, y_min, y_max) =
        scored.iter().fold((0.0f64, f64::MAX, f64::MIN), |(x, lo, hi), (t, s, _)| {
            (x.max(*t), lo.min(*s), hi.max(*s))
        });
    let axes = Axes { title, x_desc: "seconds per scene (median)", x_end: x_max * 1.1 };
    let mut chart = axes.frame(area, (y_min, y_max), text)?;
    let mut views: Vec<usize> = scored.iter().map(|(_, _, p)| p.knobs.views).collect();
    views.sort_unstable();
    views.dedup();
    for (i, v) in views.iter().enumerate() {
        let colour = VIEW_COLOURS[i % VIEW_COLOURS.len()];
        let series = chart
            .draw_series(
                scored
                    .iter()
                    .filter(|(_, _, p)| p.knobs.views == *v)
                    .map(|(t, s, _)| Circle::new((*t, *s), 5, colour.filled())),
            )
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if text {
            series
                .label(format!("{v} views"))
                .legend(move |(x, y)| Circle::new((x + 8, y), 5, colour.filled()));
        }
    }
    let mut front: Vec<(f64, f64)> =
        scored.iter().filter(|(_, _, p)| on_front(p)).map(|(t, s, _)| (*t, *s)).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart
        .draw_series(LineSeries::new(front, BLACK.stroke_width(2)))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    if text {
        chart
            .draw_series(scored.iter().filter(|(_, _, p)| on_front(p)).map(|(t, s, p)| {
                Text::new(p.knobs.label(), (*t, *s), ("sans-serif", 11).into_font())
            }))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    points: &[SweepPoint],
    text: bool,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (left, right) = root.split_horizontally(root.dim_in_pixel().0 / 2);
    panel(
        &left,
        points,
        "instance mIoU vs time (Pareto front in black)",
        |p| p.instance_miou.map(|v| 100.0 * v),
        |p| p.pareto_instance,
        text,
    )?;
    panel(&right, points, "PSNR (dB) vs time", |p| p.psnr, |p| p.pareto_psnr, text)?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))
}

/// Writes `sweep.png` and `sweep.svg` into `out`.
pub fn chart(points: &[SweepPoint], out: &Path) -> anyhow::Result<()> {
    let text = register_font();
    let png = out.join("sweep.png");
    draw(BitMapBackend::new(&png, (1200, 520)).into_drawing_area(), points, text)
        .with_context(|| format!("drawing {}", png.display()))?;
    let svg = out.join("sweep.svg");
    draw(SVGBackend::new(&svg, (1200, 520)).into_drawing_area(), points, text)
        .with_context(|| format!("drawing {}", svg.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_only_unbeaten_points() {
        let p = |seconds, miou: f64| SweepPoint {
            knobs: Knobs { views: 2, voxel_fraction: 0.01, cluster_samples: 1000 },
            seconds,
            instance_miou: Some(miou),
            psnr: Some(miou),
            pareto_instance: false,
            pareto_psnr: false,
        };
        let mut points = vec![p(1.0, 0.5), p(2.0, 0.4), p(2.0, 0.7), p(3.0, 0.7), p(0.5, 0.1)];
        mark_pareto(&mut points);
        let front: Vec<bool> = points.iter().map(|p| p.pareto_instance).collect();
        assert_eq!(front, [true, false, true, false, true]);
    }
}
