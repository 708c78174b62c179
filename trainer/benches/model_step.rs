//! Throughput of the network on the CPU: one forward + backward pass of the default
//! configuration (128×128, 4 views) on `Device::flex().autodiff()`, reported as time and
//! effective GFLOP/s (analytic model FLOPs: backward counted as twice the forward); one full
//! training step (forward, rendering of 4 input + 1 target views, the five losses, backward
//! and the AdamW update) on a synthesized scene with the share of each part; and — when
//! `ORT_DYLIB_PATH` is set — the exported graph's forward in ONNX Runtime at 8 and 16 views.
//! Run with `cargo bench -p inssplat-trainer --bench model_step` (env `STEPS` = timed steps).

use std::time::{Duration, Instant};

use burn::module::Module;
use burn::optim::{AdamWConfig, GradientsParams};
use burn::prelude::*;
use burn::tensor::Distribution;
use inssplat_synth::{Furniture, Split, Structure};
use inssplat_trainer::export::{ExportMeta, Weights, to_onnx_bytes};
use inssplat_trainer::loss::LossConfig;
use inssplat_trainer::model::{InsSplatNet, ModelConfig};
use inssplat_trainer::train::sample::{DataSpec, Sampler, Source, ViewPlan};
use inssplat_trainer::train::step::objective;
use inssplat_trainer::train::{TrainConfig, label_cache, update};

fn median(mut times: Vec<Duration>) -> Duration {
    times.sort();
    times[times.len() / 2]
}

/// A scalar touching every output, so every head receives a gradient.
fn step(net: &InsSplatNet, images: Tensor<4>) {
    let out = net.forward(images).expect("forward");
    let loss = out.camera.mean()
        + out.depth.mean()
        + out.depth_conf.log().mean()
        + out.gaussians.mean()
        + out.instance.powi_scalar(2).mean()
        + out.semantic.powi_scalar(2).mean();
    let grads = loss.backward();
    drop(grads);
}

fn bench_train_step(config: &ModelConfig, views: usize, steps: usize) {
    let device = Device::flex().autodiff();
    let net = config.init(&device).expect("config");
    let size = config.image_size;
    println!(
        "model: dim {} depth {} heads {} decoder {} sem {} -> {:.2} M parameters",
        config.dim,
        config.depth,
        config.heads,
        config.decoder_dim,
        config.sem_dim,
        net.num_params() as f64 / 1e6
    );
    let images =
        || Tensor::<4>::random([views, 3, size, size], Distribution::Uniform(0.0, 1.0), &device);
    step(&net, images());
    let times: Vec<Duration> = (0..steps)
        .map(|_| {
            let x = images();
            let t = Instant::now();
            step(&net, x);
            t.elapsed()
        })
        .collect();
    let t = median(times.clone());
    let flops = 3 * net.forward_flops(views);
    println!(
        "train step (forward+backward), {views} views {size}x{size}: median {:.3} s over {steps} (min {:.3} s), \
         {:.2} GFLOP model -> {:.1} GFLOP/s effective",
        t.as_secs_f64(),
        times.iter().min().unwrap().as_secs_f64(),
        flops as f64 / 1e9,
        flops as f64 / 1e9 / t.as_secs_f64()
    );
    let fwd = net.forward_flops(views);
    let inference = Device::flex();
    let net = config.init(&inference).expect("config");
    let x =
        Tensor::<4>::random([views, 3, size, size], Distribution::Uniform(0.0, 1.0), &inference);
    let _ = net.forward(x.clone()).expect("forward");
    let t = Instant::now();
    let _ = net.forward(x).expect("forward");
    let e = t.elapsed().as_secs_f64();
    println!(
        "burn forward only (no autodiff), {views} views: {e:.3} s, {:.1} GFLOP/s",
        fwd as f64 / 1e9 / e
    );
}

/// One real training step at `views` input views + 1 target, median of `steps`.
fn bench_objective_step(config: &ModelConfig, views: usize, steps: usize) {
    let labels = match label_cache() {
        Ok(l) => l,
        Err(e) => return println!("full training step skipped: {e} (source .deps/env)"),
    };
    let furniture = match Furniture::from_env() {
        Furniture::Catalog(dir) if dir.is_dir() => Some(dir),
        _ => None,
    };
    let data = DataSpec::Synth {
        split: Split::Train,
        furniture_dir: furniture,
        size: config.image_size as u32,
        structure: Structure::Instances,
        antialias: 1,
    };
    let plan = ViewPlan {
        min_views: views,
        max_views: views,
        targets: 1,
        reuse: 1,
        first_scene: 0,
        window: None,
    };
    let sampler = Sampler { source: Source::open(&data).expect("synth"), plan, seed: 0, labels };
    let train = TrainConfig::new(config.clone(), LossConfig::new());
    let device = Device::flex().autodiff();
    let mut net = config.init(&device).expect("config");
    let mut optim = AdamWConfig::new().init();
    let mut rows = Vec::new();
    for i in 0..=steps {
        let sample = sampler.sample(i as u64).expect("sample");
        let t = Instant::now();
        let obj = objective(&net, &sample, &train.loss, &device).expect("objective");
        let _ = obj.values();
        let tb = Instant::now();
        let grads = GradientsParams::from_grads(obj.total.backward(), &net);
        net = update(net, &mut optim, grads, 1e-4, &train);
        let backward = tb.elapsed();
        if i > 0 {
            rows.push([t.elapsed(), obj.forward_time, obj.render_time, obj.loss_time, backward]);
        }
    }
    rows.sort_by_key(|r| r[0]);
    let [total, forward, render, loss, backward] = rows[rows.len() / 2];
    let share = |d: Duration| 100.0 * d.as_secs_f64() / total.as_secs_f64();
    let flops = 3 * net.forward_flops(views);
    println!(
        "full training step, {views} views + 1 target at {0}x{0}: median {1:.3} s over {steps} -> {2:.0} steps/hour; \
         forward {3:.0}%, render {4:.0}%, losses {5:.0}%, backward+update {6:.0}% (render backward included); \
         network {7:.1} GFLOP/s effective",
        config.image_size,
        total.as_secs_f64(),
        3600.0 / total.as_secs_f64(),
        share(forward),
        share(render),
        share(loss),
        share(backward),
        flops as f64 / 1e9 / total.as_secs_f64(),
    );
}

fn bench_ort(config: &ModelConfig, steps: usize) {
    let Ok(path) = std::env::var("ORT_DYLIB_PATH") else {
        println!("ORT_DYLIB_PATH unset: skipping the ONNX Runtime timing (source .deps/env)");
        return;
    };
    let net = config.init(&Device::flex()).expect("config");
    let bytes = to_onnx_bytes(
        &net,
        &ExportMeta { model_version: "bench".into(), train_steps: 0, weights: Weights::F32 },
    )
    .expect("export");
    let env = ort::init_from(&path)
        .expect("load ONNX Runtime")
        .with_name("inssplat-bench")
        .build()
        .expect("environment");
    let builder = ort::session::Session::builder(&env).expect("builder");
    let mut builder = builder.with_intra_threads(2).expect("threads");
    let mut session = builder.commit_from_memory(&bytes).expect("session");
    let size = config.image_size;
    for views in [8usize, 16] {
        let data = vec![0.5f32; views * 3 * size * size];
        let mut run = || {
            let input = ort::value::Tensor::from_array(([views, 3, size, size], data.clone()))
                .expect("input");
            let t = Instant::now();
            let out = session.run(ort::inputs!["images" => input]).expect("run");
            drop(out);
            t.elapsed()
        };
        run();
        let times: Vec<Duration> = (0..steps).map(|_| run()).collect();
        let t = median(times).as_secs_f64();
        let flops = net.forward_flops(views) as f64;
        println!(
            "ONNX Runtime forward, {views} views: median {t:.3} s ({:.1} GFLOP/s effective)",
            flops / 1e9 / t
        );
    }
}

fn main() {
    let steps = std::env::var("STEPS").ok().and_then(|s| s.parse().ok()).unwrap_or(3);
    let config = ModelConfig::new();
    bench_train_step(&config, 4, steps);
    bench_objective_step(&config, 4, steps);
    bench_ort(&config, steps);
}
