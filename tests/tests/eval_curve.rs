//! `inssplat-eval curve` end to end: a real `score` report (tiny exported network, one
//! procedural test-split scene) placed at several CPU hours for two runs; the table, the chart
//! and the named errors.

use inssplat_e2e::inssplat_eval;
use serde_json::Value;

use crate::support::{self, s, score};

/// `inssplat-eval curve` places score reports at the hours given, one line a run: the table
/// holds each report's own scores at the view count asked, the chart is drawn, and a view
/// count a report lacks, a malformed point and a missing file are named errors.
#[test]
fn curve_draws_runs_against_cpu_hours() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = support::tiny_model_and_test_data(dir.path(), 1);
    let eval = dir.path().join("eval");
    let out = score(&data, "2", &model, &["--out", s(&eval)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let file = eval.join("eval.json");
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    let metric = |name: &str| report["summaries"][0]["metrics"][name][0].as_f64().unwrap();
    let point = |run: &str, hours: &str| format!("{run}:{hours}:{}", file.display());
    let chart = dir.path().join("curve");
    let out = inssplat_eval(&[
        "curve",
        "--views",
        "2",
        "--out",
        s(&chart),
        "--point",
        &point("scratch", "0.5"),
        "--point",
        &point("scratch", "1.5"),
        "--point",
        &point("encoder", "1"),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let table = std::fs::read_to_string(chart.join("curve.md")).unwrap();
    let row = format!(
        "| encoder | 1.00 | {:.3} | {:.1} | {:.1} |",
        metric("depth_abs_rel"),
        100.0 * metric("semantic_miou"),
        100.0 * metric("instance_miou")
    );
    assert!(table.contains(&row), "{row} not in\n{table}");
    assert_eq!(table.lines().filter(|l| l.starts_with("| scratch |")).count(), 2, "{table}");
    assert_eq!(String::from_utf8_lossy(&out.stdout).lines().next(), table.lines().next());
    let png = image::open(chart.join("curve.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1500, 500));
    assert!(std::fs::read_to_string(chart.join("curve.svg")).unwrap().contains("<svg"));
    for (args, named) in [
        (vec!["--views", "8", "--point", &point("a", "1")], "no scores at 8 views"),
        (vec!["--point", "a:soon:x.json"], "hours \"soon\""),
        (vec!["--point", "a:1:/nonexistent/eval.json"], "/nonexistent/eval.json"),
    ] {
        let out = inssplat_eval(&[&["curve", "--out", s(&chart)], &args[..]].concat());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains(named), "{args:?}: {stderr}");
    }
}
