//! Timing of the text side as the server uses it: loading the model, embedding a 40-label
//! vocabulary in one batch (what a cold `LabelCache` does), serving it again from the cache,
//! and embedding one query. Run with `cargo bench -p inssplat-text` after `source .deps/env`;
//! it prints the median and the fastest of several runs.

use std::time::{Duration, Instant};

use inssplat_text::{LabelCache, TextEmbedder};

const LABELS: [&str; 40] = [
    "chair",
    "armchair",
    "office chair",
    "stool",
    "bench",
    "sofa",
    "table",
    "coffee table",
    "dining table",
    "desk",
    "bed",
    "bunk bed",
    "crib",
    "wardrobe",
    "dresser",
    "chest of drawers",
    "bookshelf",
    "cabinet",
    "kitchen cabinet",
    "refrigerator",
    "oven",
    "stove",
    "sink",
    "washing machine",
    "toilet",
    "bathtub",
    "shower",
    "mirror",
    "lamp",
    "floor lamp",
    "ceiling light",
    "television",
    "computer monitor",
    "plant",
    "vase",
    "rug",
    "curtain",
    "door",
    "window",
    "radiator",
];

const QUERY: &str = "somewhere comfortable to sit and read";

fn time<T>(runs: usize, mut f: impl FnMut() -> T) -> (Duration, Duration) {
    let mut times: Vec<Duration> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(f());
            t.elapsed()
        })
        .collect();
    times.sort();
    (times[runs / 2], times[0])
}

fn report(what: &str, (median, min): (Duration, Duration)) {
    println!("{what:<40} median {:>9.3} ms   min {:>9.3} ms", ms(median), ms(min));
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn main() {
    report("load model", time(3, || TextEmbedder::from_env().expect("model (source .deps/env)")));
    let embedder = TextEmbedder::from_env().expect("model");
    // Warm up allocator and thread pool once.
    embedder.embed(&LABELS).unwrap();
    report("40 labels, one batch (cold cache)", time(10, || embedder.embed(&LABELS).unwrap()));
    report("1 query", time(20, || embedder.embed_one(QUERY).unwrap()));
    let cache = LabelCache::new(embedder);
    cache.embed(&LABELS).unwrap();
    report("40 labels, warm LabelCache", time(20, || cache.embed(&LABELS).unwrap()));
    report(
        "40 labels + 1 query (cold, as a scene)",
        time(10, || {
            let e = cache.embedder().unwrap();
            (e.embed(&LABELS).unwrap(), e.embed_one(QUERY).unwrap())
        }),
    );
}
