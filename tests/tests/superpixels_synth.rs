//! The colour superpixels on synthesized test-split views (the evaluation's furniture at
//! 128×128): the segments must follow the objects' outlines (almost every pixel shares its
//! segment with pixels of its own instance), must be large enough to average over, and
//! snapping an embedding map blurred across the outlines (as the decoder's upsampled maps are)
//! to them must give more pixels back to their own instance than the blurred map gives; so
//! must voting an id map whose outlines are shifted by two pixels over them.

use inssplat_synth::{self as synth, Furniture, Split, SynthConfig};
use inssplat_understand::superpixel::{SuperpixelParams, segment, snap, vote};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SIZE: usize = 128;
/// Share of the pixels that must carry their segment's majority instance (measured: 0.986
/// over the 12 views below).
const MIN_PURITY: f64 = 0.97;
/// Fewest pixels a segment must average over, in the mean (measured: 146).
const MIN_MEAN_SIZE: f64 = 40.0;
/// Nearest-prototype accuracy the snapping must add to the blurred map (measured: 0.938
/// blurred over 9×9 pixels, about a patch of the network, 0.964 snapped).
const MIN_GAIN: f64 = 0.015;
/// Share of pixels with their own id that voting must add to an id map shifted by 2 pixels
/// (measured: 0.928 shifted, 0.954 voted).
const MIN_VOTE_GAIN: f64 = 0.015;

/// Each instance's random unit embedding, painted on its pixels, box-blurred over `radius`
/// pixels and perturbed by noise: `[8][pixels]`.
fn blurred_embeddings(
    ids: &[u16],
    radius: isize,
    rng: &mut ChaCha8Rng,
) -> (Vec<f32>, Vec<[f32; 8]>) {
    let top = *ids.iter().max().unwrap() as usize;
    let protos: Vec<[f32; 8]> = (0..=top)
        .map(|_| {
            let v: [f32; 8] = std::array::from_fn(|_| rng.random_range(-1.0..1.0f32));
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / n)
        })
        .collect();
    let mut map = vec![0.0; 8 * SIZE * SIZE];
    for y in 0..SIZE as isize {
        for x in 0..SIZE as isize {
            let mut sum = [0.0f32; 8];
            for dy in -radius..=radius {
                for dx in -radius..=radius {
                    let (sx, sy) = (
                        (x + dx).clamp(0, SIZE as isize - 1),
                        (y + dy).clamp(0, SIZE as isize - 1),
                    );
                    let p = &protos[ids[sy as usize * SIZE + sx as usize] as usize];
                    sum.iter_mut().zip(p).for_each(|(s, v)| *s += v);
                }
            }
            for (c, s) in sum.iter().enumerate() {
                map[c * SIZE * SIZE + y as usize * SIZE + x as usize] = s
                    / ((2 * radius + 1) * (2 * radius + 1)) as f32
                    + rng.random_range(-0.2..0.2f32);
            }
        }
    }
    (map, protos)
}

/// Share of pixels whose nearest prototype (cosine) is their own instance's.
fn accuracy(map: &[f32], ids: &[u16], protos: &[[f32; 8]]) -> f64 {
    let n = SIZE * SIZE;
    let right = (0..n)
        .filter(|&p| {
            let f: [f32; 8] = std::array::from_fn(|c| map[c * n + p]);
            let best = (0..protos.len()).max_by(|&a, &b| {
                let dot = |k: usize| protos[k].iter().zip(&f).map(|(x, y)| x * y).sum::<f32>();
                dot(a).total_cmp(&dot(b))
            });
            best == Some(ids[p] as usize)
        })
        .count();
    right as f64 / n as f64
}

#[test]
fn superpixels_follow_the_outlines_and_snapping_and_voting_restore_them() {
    let cfg = SynthConfig::new(Split::Test, Furniture::from_env());
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (mut pure, mut pixels, mut segments_total) = (0usize, 0usize, 0usize);
    let (mut blurred_acc, mut snapped_acc) = (0.0, 0.0);
    let (mut shifted_right, mut voted_right) = (0usize, 0usize);
    let mut views = 0;
    for index in 0..3 {
        let scene = synth::generate_split(index, &cfg).unwrap().scene;
        for frame in scene.frames.iter().step_by(6).take(4) {
            let ids = frame.instances.as_deref().expect("synthesized frames carry instance masks");
            assert_eq!(ids.len(), SIZE * SIZE);
            let segments = segment(&frame.planar_rgb(), SIZE, SIZE, &SuperpixelParams::default());
            let count = *segments.iter().max().unwrap() as usize + 1;
            let top = *ids.iter().max().unwrap() as usize + 1;
            let mut votes = vec![0usize; count * top];
            for (&s, &i) in segments.iter().zip(ids) {
                votes[s as usize * top + i as usize] += 1;
            }
            pure += votes.chunks_exact(top).map(|v| v.iter().max().unwrap()).sum::<usize>();
            pixels += ids.len();
            segments_total += count;

            let (mut map, protos) = blurred_embeddings(ids, 4, &mut rng);
            blurred_acc += accuracy(&map, ids, &protos);
            snap(&mut map, &segments);
            snapped_acc += accuracy(&map, ids, &protos);

            let mut shifted: Vec<u32> =
                (0..ids.len()).map(|p| u32::from(ids[p - (p % SIZE).min(2)])).collect();
            shifted_right += shifted.iter().zip(ids).filter(|(s, i)| **s == u32::from(**i)).count();
            vote(&mut shifted, &segments);
            voted_right += shifted.iter().zip(ids).filter(|(s, i)| **s == u32::from(**i)).count();
            views += 1;
        }
    }
    let purity = pure as f64 / pixels as f64;
    let mean_size = pixels as f64 / segments_total as f64;
    let (blurred_acc, snapped_acc) = (blurred_acc / views as f64, snapped_acc / views as f64);
    let (shifted_acc, voted_acc) =
        (shifted_right as f64 / pixels as f64, voted_right as f64 / pixels as f64);
    eprintln!(
        "{views} views: purity {purity:.3}, mean segment {mean_size:.0} px, accuracy blurred {blurred_acc:.3} snapped {snapped_acc:.3}, ids shifted {shifted_acc:.3} voted {voted_acc:.3}"
    );
    assert!(purity >= MIN_PURITY, "segments straddle the outlines: purity {purity:.3}");
    assert!(mean_size >= MIN_MEAN_SIZE, "segments too small to average over: {mean_size:.1} px");
    assert!(
        snapped_acc >= blurred_acc + MIN_GAIN,
        "snapping gave {snapped_acc:.3} against {blurred_acc:.3} blurred"
    );
    assert!(
        voted_acc >= shifted_acc + MIN_VOTE_GAIN,
        "voting gave {voted_acc:.3} against {shifted_acc:.3} shifted"
    );
}
