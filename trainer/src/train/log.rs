//! The training log: one CSV row per step (`RUN/train_log.csv`) and per validation
//! (`RUN/val_log.csv`), and the loss-curve chart `RUN/loss.png` drawn from them with plotters
//! (total and every term, log scale, training curve smoothed, validation as points).
//! On resume, rows of steps past the checkpoint are dropped so the log matches the run.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::step::LossValues;

pub const TRAIN_HEADER: &str = "step,lr,total,rgb,geometry,instance,semantic,boundary,step_s,forward_s,render_s,backward_s,data_wait_s,elapsed_s,render_backward_s";
pub const VAL_HEADER: &str = "step,total,rgb,geometry,instance,semantic,boundary";

/// Appends rows to a CSV file that starts with `header`.
pub struct CsvLog {
    path: PathBuf,
    file: File,
}

impl CsvLog {
    /// Opens `path` for appending, keeping only rows whose step is below `keep_below`
    /// (all rows of an uninterrupted run; those before the checkpoint of a resumed one).
    pub fn open(path: &Path, header: &str, keep_below: u64) -> std::io::Result<Self> {
        let mut rows = vec![header.to_string()];
        if let Ok(file) = File::open(path) {
            rows.extend(BufReader::new(file).lines().skip(1).map_while(Result::ok).filter(|l| {
                l.split(',')
                    .next()
                    .and_then(|s| s.parse::<u64>().ok())
                    .is_some_and(|s| s < keep_below)
            }));
        }
        let tmp = path.with_extension("csv.tmp");
        std::fs::write(&tmp, rows.join("\n") + "\n")?;
        std::fs::rename(&tmp, path)?;
        let file = OpenOptions::new().append(true).open(path)?;
        Ok(Self { path: path.to_path_buf(), file })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one row.
    pub fn row(&mut self, values: &[String]) -> std::io::Result<()> {
        writeln!(self.file, "{}", values.join(","))
    }
}

/// The CSV cells of a loss record after the step column.
pub fn loss_cells(v: &LossValues) -> Vec<String> {
    [v.total, v.rgb, v.geometry, v.instance, v.semantic, v.boundary]
        .iter()
        .map(|x| format!("{x:.6}"))
        .collect()
}

/// Reads columns `names` of a CSV log as (step, values) rows; unparsable rows are skipped.
fn read_columns(path: &Path, names: &[&str]) -> Vec<(f64, Vec<f64>)> {
    let Ok(file) = File::open(path) else { return Vec::new() };
    let mut lines = BufReader::new(file).lines().map_while(Result::ok);
    let Some(header) = lines.next() else { return Vec::new() };
    let cols: Vec<&str> = header.split(',').collect();
    let Some(idx) =
        names.iter().map(|n| cols.iter().position(|c| c == n)).collect::<Option<Vec<_>>>()
    else {
        return Vec::new();
    };
    lines
        .filter_map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            let step = cells.first()?.parse().ok()?;
            let values =
                idx.iter().map(|&i| cells.get(i)?.parse().ok()).collect::<Option<Vec<f64>>>()?;
            Some((step, values))
        })
        .collect()
}

/// Exponential moving average with the given smoothing (0 = none).
fn smooth(values: &[f64], alpha: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(values.len());
    let mut acc = None;
    for &v in values {
        let next = match acc {
            None => v,
            Some(a) => alpha * a + (1.0 - alpha) * v,
        };
        acc = Some(next);
        out.push(next);
    }
    out
}

/// Registers DejaVu Sans for chart text; false (and charts without text) if it is missing.
fn register_font() -> bool {
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

/// Draws `out` (PNG) from the training and validation logs.
pub fn draw_chart(train_csv: &Path, val_csv: &Path, out: &Path) -> Result<(), String> {
    const TERMS: [&str; 6] = ["total", "rgb", "geometry", "instance", "semantic", "boundary"];
    let train = read_columns(train_csv, &TERMS);
    if train.is_empty() {
        return Ok(());
    }
    let val = read_columns(val_csv, &["total"]);
    let with_text = register_font();
    let root = BitMapBackend::new(out, (1000, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let x_max = train.last().map_or(1.0, |r| r.0).max(1.0);
    let positive = train
        .iter()
        .flat_map(|r| r.1.iter().copied())
        .chain(val.iter().map(|r| r.1[0]))
        .filter(|v| *v > 0.0);
    let (lo, hi) = positive.fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    // Headroom above the highest curve keeps the legend (upper right) off the curves.
    let (lo, hi) = if lo <= hi { (lo * 0.8, hi * 8.0) } else { (1e-3, 1.0) };
    let mut builder = ChartBuilder::on(&root);
    builder.margin(12);
    if with_text {
        builder
            .caption("inssplat training loss", ("sans-serif", 22))
            .x_label_area_size(40)
            .y_label_area_size(70);
    }
    let mut chart =
        builder.build_cartesian_2d(0.0..x_max, (lo..hi).log_scale()).map_err(|e| e.to_string())?;
    if with_text {
        chart
            .configure_mesh()
            .x_desc("step")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_desc("loss (unweighted terms)")
            .draw()
            .map_err(|e| e.to_string())?;
    }
    let steps: Vec<f64> = train.iter().map(|r| r.0).collect();
    for (t, name) in TERMS.iter().enumerate() {
        let colour = Palette99::pick(t).to_rgba();
        let values: Vec<f64> = train.iter().map(|r| r.1[t]).collect();
        let curve = smooth(&values, 0.9);
        let points = steps.iter().zip(curve).filter(|(_, v)| *v > 0.0).map(|(s, v)| (*s, v));
        let width = if t == 0 { 3 } else { 1 };
        let series = chart
            .draw_series(LineSeries::new(points, colour.stroke_width(width)))
            .map_err(|e| e.to_string())?;
        if with_text {
            series.label(*name).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
        }
    }
    if !val.is_empty() {
        let series = chart
            .draw_series(
                val.iter()
                    .filter(|r| r.1[0] > 0.0)
                    .map(|r| Circle::new((r.0, r.1[0]), 5, BLACK.filled())),
            )
            .map_err(|e| e.to_string())?;
        if with_text {
            series.label("val total").legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
        }
    }
    if with_text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())
}
