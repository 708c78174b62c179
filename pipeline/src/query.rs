//! `inssplat query OUT "text"`: which instances of a saved reconstruction the text names
//! (cosine of the text embedding with each instance's semantic prototype, under the
//! `QueryRule`), and the mask of the answer in every input view, from the view's instance ids
//! (`ids/NNN.png`, at the photo's resolution up to the mask size; rendered from the Gaussians at
//! the photo's resolution for a folder without them), written as `OUT/query/<text>/NNN.png`.

use std::path::PathBuf;

use anyhow::Context;
use image::{GrayImage, Luma};
use inssplat_proto::api::{QueryMatch, QueryResponse, RleMask, ViewMask};
use inssplat_raster::masks::{ids_mask, render_instance_ids};
use inssplat_text::LabelCache;
use inssplat_understand::label::{QueryRule, query};
use rayon::prelude::*;

use crate::output::{png_bytes, write_atomic};
use crate::reconstruct::{max_instance_id, own_label_scores};
use crate::saved::Saved;

/// A file-name-safe form of the query text.
fn slug(text: &str) -> String {
    let s: String = text
        .trim()
        .chars()
        .map(|c| if c.is_alphanumeric() { c.to_ascii_lowercase() } else { '_' })
        .collect();
    if s.is_empty() { "query".into() } else { s }
}

/// Answers `text` on `saved`: the matching instances, best first, each with its mask in every
/// view (run-length encoded, and as `DIR/id<ID>_view<NNN>.png`); returns the answer and DIR.
pub fn run_query(
    saved: &Saved,
    labels: &LabelCache,
    text: &str,
) -> anyhow::Result<(QueryResponse, PathBuf)> {
    if text.trim().is_empty() {
        anyhow::bail!("the query text is empty");
    }
    let embedding = labels.embedder()?.embed_one(text).context("embedding the query text")?;
    let prototypes = saved.prototypes();
    let own_scores = own_label_scores(&prototypes, &saved.doc.instances);
    let hits = query(&prototypes, &embedding, &own_scores, &QueryRule::default())?;
    let dir = saved.dir.join("query").join(slug(text));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let k = max_instance_id(&saved.doc.instances);
    let maps: Vec<(u32, u32, Vec<u32>)> = saved
        .cameras
        .par_iter()
        .enumerate()
        .map(|(view, camera)| -> anyhow::Result<(u32, u32, Vec<u32>)> {
            let path = saved.dir.join("ids").join(format!("{view:03}.png"));
            if path.is_file() {
                let ids = image::open(&path)
                    .with_context(|| format!("{}: not an instance id map", path.display()))?
                    .into_luma16();
                let (w, h) = ids.dimensions();
                return Ok((w, h, ids.into_raw().into_iter().map(u32::from).collect()));
            }
            let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
            Ok((w, h, render_instance_ids(&saved.scene, camera, k)?))
        })
        .collect::<Result<_, _>>()?;
    let label_of = |id: u32| {
        saved
            .doc
            .instances
            .iter()
            .find(|i| i.id == id)
            .map_or_else(|| "unknown".into(), |i| i.label.clone())
    };
    let mut matches = Vec::new();
    for hit in &hits {
        let mut masks = Vec::new();
        for (view, &(w, h, ref map)) in maps.iter().enumerate() {
            let mask = ids_mask(map, &[hit.id]);
            let img = GrayImage::from_fn(w, h, |x, y| {
                Luma([if mask[(y * w + x) as usize] { 255 } else { 0 }])
            });
            let path = dir.join(format!("id{}_view{view:03}.png", hit.id));
            write_atomic(&path, &png_bytes(&img))?;
            masks.push(ViewMask {
                view,
                png_url: path.display().to_string(),
                rle: RleMask::encode(w, h, &mask),
            });
        }
        matches.push(QueryMatch {
            instance_id: hit.id,
            label: label_of(hit.id),
            score: hit.score,
            masks,
        });
    }
    let message = matches.is_empty().then(|| {
        let rule = QueryRule::default();
        let best = prototypes
            .iter()
            .zip(&own_scores)
            .map(|(p, own)| (p.id, p.embedding.iter().zip(&embedding).map(|(a, b)| a * b).sum::<f32>(), *own))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((id, score, own)) => format!(
                "nothing in this scene matches \"{text}\": the closest, instance {id} \"{}\", scores {score:.2} (a match needs ≥ {:.2} and within {:.2} of its own label's {own:.2})",
                label_of(id),
                rule.min_score,
                rule.label_margin,
            ),
            None => format!("nothing in this scene matches \"{text}\" (the scene has no instances)"),
        }
    });
    Ok((QueryResponse { text: text.to_string(), matches, message }, dir))
}
