//! L_match, the loss on the attention itself: its value worked out by hand, its gradient
//! against finite differences, and its targets: a view identical to view 0 matches every token
//! to itself, and a synthesized scene's overlapping views find view 0's tokens for most of
//! theirs.

use burn::prelude::*;
use inssplat_trainer::loss::{attention_match_loss, match_targets};

use crate::loss_instance::check_gradient;
use crate::loss_point_map::synthesized;

fn tensor(values: &[f32], shape: [usize; 3]) -> Tensor<3> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), &Device::flex())
}

#[test]
fn loss_attention_match_is_the_cross_entropy_over_view_zeros_tokens() {
    // Two views of two tokens, head width 1 (scale 1): view 1's logits against view 0's keys
    // (1, −1) are (q, −q).
    let queries = tensor(&[9.0, 9.0, 2.0, -1.0], [2, 2, 1]);
    let keys = tensor(&[1.0, -1.0, 7.0, 7.0], [2, 2, 1]);
    // Token 0 of view 1 should look at token 0, token 1 at token 1.
    let got = f64::from(
        attention_match_loss(queries.clone(), keys.clone(), &[0, 1]).unwrap().into_scalar::<f32>(),
    );
    let ce =
        |logits: [f64; 2], target: usize| (logits[0].exp() + logits[1].exp()).ln() - logits[target];
    let want = (ce([2.0, -2.0], 0) + ce([-1.0, 1.0], 1)) / 2.0;
    assert!((got - want).abs() < 1e-5, "L_match {got}, expected {want}");
    // A token without a target does not count.
    let one = f64::from(
        attention_match_loss(queries.clone(), keys.clone(), &[-1, 1]).unwrap().into_scalar::<f32>(),
    );
    assert!((one - ce([-1.0, 1.0], 1)).abs() < 1e-5, "{one}");
    let none = attention_match_loss(queries.clone(), keys.clone(), &[-1, -1]).unwrap();
    assert_eq!(none.into_scalar::<f32>(), 0.0);
    assert!(
        attention_match_loss(queries, keys, &[0]).is_err(),
        "targets of the wrong length are refused"
    );
}

#[test]
fn loss_attention_match_gradient_matches_finite_differences() {
    let values = [
        0.3, -0.7, 1.1, 0.2, -0.4, 0.9, 0.5, 0.1, -1.2, 0.6, 0.8,
        -0.3, // view 0: 3 tokens × 2, twice
        0.7, 0.4, -0.6, 1.3, 0.2, -0.9, 1.0, -0.2, 0.3, 0.5, -0.8, 0.6, // view 1
    ];
    let targets = [2, -1, 0];
    // Queries in channels 0–1, keys in 2–3 of one [1, V·3, 4, 1]-shaped input.
    check_gradient(&values, [2, 3, 4, 1], |x| {
        let x = x.reshape([2, 3, 4]);
        attention_match_loss(x.clone().narrow(2, 0, 2), x.narrow(2, 2, 2), &targets).unwrap()
    });
}

#[test]
fn match_targets_follow_the_surface_into_view_zero() {
    let (_dir, scene) = synthesized(3, 64, 64, 16, (0.5, 0.6));
    let depth = |f: usize| scene.frames[f].depth.clone().unwrap();
    // View 0 twice: every token sees itself.
    let same = [scene.frames[0].camera, scene.frames[0].camera];
    let targets = match_targets(&same, &[depth(0), depth(0)].concat(), 64, 8).unwrap();
    assert_eq!(targets, (0..64).collect::<Vec<i64>>());
    // Every second of 16 views along the path: most tokens find a target, and not the token at
    // their own place.
    let cameras: Vec<_> = [0, 2, 4].iter().map(|&f| scene.frames[f].camera).collect();
    let targets = match_targets(&cameras, &[depth(0), depth(2), depth(4)].concat(), 64, 8).unwrap();
    assert_eq!(targets.len(), 2 * 64);
    let found = targets.iter().filter(|&&t| t >= 0).count();
    let moved =
        targets.iter().enumerate().filter(|&(i, &t)| t >= 0 && t != (i % 64) as i64).count();
    assert!(found > 64, "{found} of 128 tokens found view 0's");
    assert!(moved > found / 4, "{moved} of {found} moved: the views are not the same");
    // The views move the other way from view 0 than view 0 from them: wrong frames would not.
    let back =
        match_targets(&[cameras[1], cameras[0]], &[depth(2), depth(0)].concat(), 64, 8).unwrap();
    let there_and_back = (0..64)
        .filter(|&i| {
            targets[i] >= 0
                && back
                    .get(targets[i] as usize)
                    .is_some_and(|&j| j >= 0 && (j - i as i64).abs() <= 9)
        })
        .count();
    assert!(
        there_and_back * 4 > found / 2 * 3,
        "{there_and_back} of view 2's tokens come back within a token"
    );
}
