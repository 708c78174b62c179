//! `inssplat-eval curve`: training runs compared at equal compute. Each point is one
//! checkpoint's `score` report (`eval.json`) placed at the CPU hours its run had spent; the
//! points of one run make its line. Drawn as three panels (depth AbsRel, semantic mIoU,
//! instance mIoU against hours, PNG and SVG) and written as a markdown table.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Deserialize;

use crate::sweep::{Axes, VIEW_COLOURS, register_font};

/// One checkpoint's scores at the CPU hours its run had spent.
#[derive(Debug, Clone, PartialEq)]
pub struct CurvePoint {
    pub run: String,
    pub hours: f64,
    pub depth_abs_rel: f64,
    /// Percent.
    pub semantic_miou: f64,
    /// Percent.
    pub instance_miou: f64,
}

/// What `curve` reads of a report.
#[derive(Deserialize)]
struct Scored {
    summaries: Vec<ScoredViews>,
}

#[derive(Deserialize)]
struct ScoredViews {
    views: usize,
    metrics: BTreeMap<String, (f64, usize)>,
}

/// `RUN:HOURS:FILE` → its parts.
pub fn parse_point(spec: &str) -> anyhow::Result<(String, f64, PathBuf)> {
    let mut parts = spec.splitn(3, ':');
    let (Some(run), Some(hours), Some(file)) = (parts.next(), parts.next(), parts.next()) else {
        bail!("--point {spec:?}: expected RUN:HOURS:FILE");
    };
    let hours: f64 = hours
        .parse()
        .ok()
        .filter(|h: &f64| h.is_finite() && *h >= 0.0)
        .with_context(|| format!("--point {spec:?}: hours {hours:?} is not a number ≥ 0"))?;
    if run.is_empty() {
        bail!("--point {spec:?}: the run has no name");
    }
    Ok((run.to_string(), hours, PathBuf::from(file)))
}

/// The scores at `views` views of the report at `path`.
pub fn read_point(run: &str, hours: f64, path: &Path, views: usize) -> anyhow::Result<CurvePoint> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let scored: Scored = serde_json::from_slice(&bytes)
        .with_context(|| format!("{}: not an `inssplat-eval score` report", path.display()))?;
    let summary = scored.summaries.iter().find(|s| s.views == views).with_context(|| {
        let had: Vec<usize> = scored.summaries.iter().map(|s| s.views).collect();
        format!("{}: no scores at {views} views (it has {had:?})", path.display())
    })?;
    let metric = |name: &str| {
        summary
            .metrics
            .get(name)
            .map(|m| m.0)
            .with_context(|| format!("{}: no {name} at {views} views", path.display()))
    };
    Ok(CurvePoint {
        run: run.to_string(),
        hours,
        depth_abs_rel: metric("depth_abs_rel")?,
        semantic_miou: 100.0 * metric("semantic_miou")?,
        instance_miou: 100.0 * metric("instance_miou")?,
    })
}

/// The points as a table, by run and then hours.
pub fn markdown(points: &[CurvePoint]) -> String {
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.run.cmp(&b.run).then(a.hours.total_cmp(&b.hours)));
    let mut out = String::from(
        "| run | CPU hours | depth AbsRel | semantic mIoU | instance mIoU |\n|---|---|---|---|---|\n",
    );
    for p in sorted {
        out += &format!(
            "| {} | {:.2} | {:.3} | {:.1} | {:.1} |\n",
            p.run, p.hours, p.depth_abs_rel, p.semantic_miou, p.instance_miou
        );
    }
    out
}

/// The runs in the order first given.
fn runs(points: &[CurvePoint]) -> Vec<&str> {
    let mut runs: Vec<&str> = Vec::new();
    for p in points {
        if !runs.contains(&p.run.as_str()) {
            runs.push(&p.run);
        }
    }
    runs
}

fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    points: &[CurvePoint],
    title: &str,
    score: fn(&CurvePoint) -> f64,
    text: bool,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e}");
    let x_max = points.iter().map(|p| p.hours).fold(0.0, f64::max).max(1e-3);
    let (lo, hi) =
        points.iter().map(score).fold((f64::MAX, f64::MIN), |(lo, hi), s| (lo.min(s), hi.max(s)));
    let axes = Axes { title, x_desc: "CPU hours", x_end: x_max * 1.05 };
    let mut chart = axes.frame(area, (lo, hi), text)?;
    for (i, run) in runs(points).into_iter().enumerate() {
        let colour = VIEW_COLOURS[i % VIEW_COLOURS.len()];
        let mut line: Vec<(f64, f64)> =
            points.iter().filter(|p| p.run == run).map(|p| (p.hours, score(p))).collect();
        line.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(line.iter().map(|&(x, y)| Circle::new((x, y), 4, colour.filled())))
            .map_err(err)?;
        chart.draw_series(LineSeries::new(line, colour.stroke_width(2))).map_err(err)?;
    }
    Ok(())
}

/// The runs' colours, in a strip above the panels (where no point can hide under them).
fn legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    points: &[CurvePoint],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow::anyhow!("{e}");
    let mut x = 60;
    for (i, run) in runs(points).into_iter().enumerate() {
        let colour = VIEW_COLOURS[i % VIEW_COLOURS.len()];
        area.draw(&PathElement::new(vec![(x, 20), (x + 24, 20)], colour.stroke_width(3)))
            .map_err(err)?;
        area.draw(&Text::new(run.to_string(), (x + 32, 12), ("sans-serif", 16).into_font()))
            .map_err(err)?;
        x += 60 + 9 * run.chars().count() as i32;
    }
    Ok(())
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    points: &[CurvePoint],
    text: bool,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let (top, root) = root.split_vertically(40);
    if text {
        legend(&top, points)?;
    }
    let panels = root.split_evenly((1, 3));
    panel(&panels[0], points, "depth AbsRel (lower is better)", |p| p.depth_abs_rel, text)?;
    panel(&panels[1], points, "semantic mIoU (%)", |p| p.semantic_miou, text)?;
    panel(&panels[2], points, "instance mIoU (%)", |p| p.instance_miou, text)?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))
}

/// Writes `curve.png`, `curve.svg` and `curve.md` into `out`.
pub fn write(points: &[CurvePoint], out: &Path) -> anyhow::Result<()> {
    if points.is_empty() {
        bail!("no points to draw");
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let text = register_font();
    let size = (1500, 500);
    let png = out.join("curve.png");
    draw(BitMapBackend::new(&png, size).into_drawing_area(), points, text)
        .with_context(|| format!("drawing {}", png.display()))?;
    let svg = out.join("curve.svg");
    draw(SVGBackend::new(&svg, size).into_drawing_area(), points, text)
        .with_context(|| format!("drawing {}", svg.display()))?;
    let md = out.join("curve.md");
    std::fs::write(&md, markdown(points)).with_context(|| format!("writing {}", md.display()))
}
