//! Embeddings from the real all-MiniLM-L6-v2 (found through INSSPLAT_TEXT_MODEL or the default
//! location): agreement with an independent numpy implementation, sane similarity ordering,
//! batching that does not change vectors, the label cache, and input normalization.

use inssplat_text::{EMBEDDING_DIM, Embedding, LabelCache, TextEmbedder, TextError, cosine};

fn embedder() -> TextEmbedder {
    TextEmbedder::from_env().expect("the model installed by scripts/setup (source .deps/env)")
}

fn max_abs_diff(a: &Embedding, b: &Embedding) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn matches_the_numpy_reference_to_1e_4() {
    let e = embedder();
    let texts: Vec<&str> = crate::vectors::REFERENCE.iter().map(|(t, _)| *t).collect();
    let batched = e.embed(&texts).unwrap();
    for ((text, want), got) in crate::vectors::REFERENCE.iter().zip(&batched) {
        let alone = e.embed_one(text).unwrap();
        for (name, v) in [("batched", got), ("alone", &alone)] {
            let diff = max_abs_diff(v, want);
            assert!(diff < 1e-4, "{text:?} ({name}): max |diff| {diff} vs reference");
        }
    }
}

#[test]
fn embedder_and_cache_can_be_shared_across_threads() {
    fn shareable<T: Send + Sync>() {}
    shareable::<TextEmbedder>();
    shareable::<LabelCache>();
}

#[test]
fn vectors_have_unit_length_and_384_dims() {
    let v = embedder().embed_one("a wooden bookshelf").unwrap();
    assert_eq!(v.len(), EMBEDDING_DIM);
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    assert!((norm - 1.0).abs() < 1e-5, "norm {norm}");
    assert!((cosine(&v, &v) - 1.0).abs() < 1e-5);
}

#[test]
fn similarity_ordering_is_sane() {
    let e = embedder();
    let [armchair, chair, banana, lamp, floor_lamp, sofa]: [Embedding; 6] = e
        .embed(&["armchair", "chair", "banana", "lamp", "floor lamp", "sofa"])
        .unwrap()
        .try_into()
        .unwrap();
    assert!(cosine(&armchair, &chair) > cosine(&armchair, &banana));
    assert!(cosine(&lamp, &floor_lamp) > cosine(&lamp, &sofa));
}

#[test]
fn batching_gives_the_vectors_of_one_at_a_time() {
    let e = embedder();
    let long = "a tall narrow bookcase with glass doors, five shelves of paperbacks and a potted \
                fern on top, standing in the corner of a sunny living room";
    // 40 texts of mixed lengths: more than one chunk, reordered by length inside `embed`.
    let mut texts: Vec<String> = (0..13)
        .flat_map(|i| [format!("chair {i}"), format!("a small side table number {i}"), long.into()])
        .collect();
    texts.push("lamp".into());
    let texts: Vec<&str> = texts.iter().map(String::as_str).collect();
    let batched = e.embed(&texts).unwrap();
    assert_eq!(batched.len(), texts.len());
    for (text, got) in texts.iter().zip(&batched) {
        let alone = e.embed_one(text).unwrap();
        let diff = max_abs_diff(got, &alone);
        assert!(diff < 1e-5, "{text:?}: batched vs alone max |diff| {diff}");
    }
}

#[test]
fn text_is_trimmed_and_empty_text_is_an_error() {
    let e = embedder();
    let plain = e.embed_one("desk").unwrap();
    let padded = e.embed_one("  desk\n\t").unwrap();
    assert!(max_abs_diff(&plain, &padded) < 1e-6);
    match e.embed(&["desk", " \n "]) {
        Err(TextError::EmptyText { index: 1 }) => {}
        other => panic!("expected EmptyText at 1, got {other:?}"),
    }
    assert!(e.embed(&[]).unwrap().is_empty());
}

#[test]
fn text_longer_than_the_model_limit_is_truncated() {
    let e = embedder();
    let long = "chair ".repeat(600);
    let v = e.embed_one(&long).unwrap();
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    assert!((norm - 1.0).abs() < 1e-5);
}

#[test]
fn label_cache_embeds_each_label_once_and_agrees_with_the_embedder() {
    let cache = LabelCache::new(embedder());
    assert!(cache.is_empty());
    let first = cache.embed(&["bed", "table", " bed "]).unwrap();
    assert_eq!(cache.len(), 2, "\"bed\" and \" bed \" are one label");
    assert!(max_abs_diff(&first[0], &first[2]) < 1e-6);
    let second = cache.embed(&["table", "window", "bed"]).unwrap();
    assert_eq!(cache.len(), 3);
    assert_eq!(second[0], first[1]);
    assert_eq!(second[2], first[0]);
    let direct = cache.embedder().unwrap().embed_one("window").unwrap();
    assert!(max_abs_diff(&second[1], &direct) < 1e-5);
    assert!(matches!(cache.embed(&["bed", ""]), Err(TextError::EmptyText { index: 1 })));
}

#[test]
fn a_label_table_round_trips_without_the_model_and_names_what_it_lacks() {
    let cache = LabelCache::new(embedder());
    let want = cache.embed(&["chair", "lamp"]).unwrap();
    let table = LabelCache::from_table(cache.entries());
    assert_eq!(table.entries().len(), 2);
    assert_eq!(table.embed(&["lamp", " chair"]).unwrap(), vec![want[1], want[0]]);
    match table.embed(&["chair", "banana"]) {
        Err(TextError::TableOnly { labels }) => assert_eq!(labels, vec!["banana".to_string()]),
        other => panic!("expected TableOnly, got {other:?}"),
    }
    let err = table.embedder().unwrap_err().to_string();
    assert!(err.contains(inssplat_text::MODEL_ENV), "{err}");
}
