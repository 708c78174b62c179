//! What an object detector's boxes say of each instance. In every view, a box's members are the
//! instances (ids of the view's instance map) with at least half their pixels inside it: the
//! object it found, which clustering may have cut into parts. The box votes for each member
//! with its score × the IoU of the box with the members' joint bounding box (how well they
//! fill it) × the share of the member's pixels inside it; each class keeps its best box's vote.
//! An instance's vote for a class is the mean of its views' votes weighted by how many of its
//! pixels each view sees, so one view's false detection, or a view that sees a sliver of it,
//! weighs little. The
//! votes then move the instance's semantic prototype toward the classes' text embeddings
//! ([`fuse_votes`]), as the shape classifier's probabilities do ([`super::shape::fuse`]).

use super::{InstancePrototype, add_direction, normalized};

/// One detected box in a view, in the pixels of that view's instance map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DetectedBox {
    /// Index into the detector's classes.
    pub class: usize,
    pub score: f32,
    /// `[x0, y0, x1, y1]`.
    pub bbox: [f32; 4],
}

/// One view's instance map and the detector's boxes in it.
#[derive(Debug, Clone, Copy)]
pub struct ViewDetections<'a> {
    /// `[height][width]` instance ids, 0 = none.
    pub ids: &'a [u32],
    pub width: usize,
    pub height: usize,
    pub boxes: &'a [DetectedBox],
}

/// One instance's votes.
#[derive(Debug, Clone, PartialEq)]
pub struct ClassVotes {
    pub id: u32,
    /// Per detector class, in [0, 1].
    pub votes: Vec<f32>,
    /// Views that see at least the minimum of its pixels.
    pub views: usize,
}

impl ClassVotes {
    /// The class of the strongest vote, and the vote (`None` when every vote is 0).
    pub fn best(&self) -> Option<(usize, f32)> {
        let (c, &v) = self.votes.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
        (v > 0.0).then_some((c, v))
    }
}

/// Each instance id seen by at least `min_pixels` pixels in some view, with its votes over
/// `classes` detector classes; in id order.
pub fn class_votes(
    views: &[ViewDetections<'_>],
    classes: usize,
    min_pixels: usize,
) -> Vec<ClassVotes> {
    let max_id = views.iter().flat_map(|v| v.ids.iter().copied()).max().unwrap_or(0) as usize;
    // Per id: Σ weight × vote per class, Σ weight, views.
    let mut sums = vec![(vec![0.0f32; classes], 0.0f32, 0usize); max_id];
    for view in views {
        let boxes = instance_boxes(view, max_id);
        let seen = |id: usize| boxes[id].0 >= min_pixels.max(1);
        let mut best = vec![vec![0.0f32; classes]; max_id];
        for b in view.boxes {
            let inside = pixels_inside(view, &b.bbox, max_id);
            let members: Vec<usize> =
                (0..max_id).filter(|&i| seen(i) && 2 * inside[i] >= boxes[i].0).collect();
            let Some(joint) = members.iter().map(|&i| boxes[i].1).reduce(union) else { continue };
            let fit = b.score * box_iou(&joint, &b.bbox);
            for i in members {
                let vote = fit * inside[i] as f32 / boxes[i].0 as f32;
                best[i][b.class] = best[i][b.class].max(vote);
            }
        }
        for (id, best) in best.iter().enumerate().filter(|(id, _)| seen(*id)) {
            let (votes, weight, count) = &mut sums[id];
            let w = boxes[id].0 as f32;
            votes.iter_mut().zip(best).for_each(|(v, b)| *v += w * b);
            *weight += w;
            *count += 1;
        }
    }
    sums.into_iter()
        .enumerate()
        .filter(|(_, (_, weight, _))| *weight > 0.0)
        .map(|(i, (mut votes, weight, views))| {
            votes.iter_mut().for_each(|v| *v /= weight);
            ClassVotes { id: i as u32 + 1, votes, views }
        })
        .collect()
}

/// Pixel count and bounding box (pixel edges) of each id 1..=`max_id` in `view` (index id − 1).
fn instance_boxes(view: &ViewDetections<'_>, max_id: usize) -> Vec<(usize, [f32; 4])> {
    let mut out = vec![(0usize, [f32::INFINITY, f32::INFINITY, 0.0f32, 0.0f32]); max_id];
    for (i, &id) in view.ids.iter().enumerate() {
        if id == 0 {
            continue;
        }
        let (x, y) = ((i % view.width) as f32, (i / view.width) as f32);
        let (count, b) = &mut out[id as usize - 1];
        *count += 1;
        *b = union(*b, [x, y, x + 1.0, y + 1.0]);
    }
    out
}

/// How many pixels of each id 1..=`max_id` have their centre inside `bbox` (index id − 1).
fn pixels_inside(view: &ViewDetections<'_>, bbox: &[f32; 4], max_id: usize) -> Vec<usize> {
    let mut inside = vec![0usize; max_id];
    let span = |lo: f32, hi: f32, n: usize| {
        let first = (lo - 0.5).ceil().max(0.0) as usize;
        let end = ((hi - 0.5).ceil().max(0.0) as usize).min(n);
        first..end
    };
    for y in span(bbox[1], bbox[3], view.height) {
        for x in span(bbox[0], bbox[2], view.width) {
            match view.ids[y * view.width + x] {
                0 => {}
                id => inside[id as usize - 1] += 1,
            }
        }
    }
    inside
}

/// The bounding box of two boxes.
fn union(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    [a[0].min(b[0]), a[1].min(b[1]), a[2].max(b[2]), a[3].max(b[3])]
}

/// Intersection over union of two `[x0, y0, x1, y1]` boxes.
pub fn box_iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let area = |b: [f32; 4]| (b[2] - b[0]).max(0.0) * (b[3] - b[1]).max(0.0);
    let inter = area([a[0].max(b[0]), a[1].max(b[1]), a[2].min(b[2]), a[3].min(b[3])]);
    let union = area(*a) + area(*b) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// Adds `weight` × Σ_c vote_c·t̂_c to each prototype that has votes, over the classes whose text
/// embeddings `class_texts` are given (`None`: a class no word of the vocabulary is near, which
/// moves nothing), and normalizes again. The sum is not normalized: weak votes move little.
pub fn fuse_votes<T: AsRef<[f32]>>(
    prototypes: &mut [InstancePrototype],
    votes: &[ClassVotes],
    class_texts: &[Option<T>],
    weight: f32,
) {
    let texts: Vec<Option<Vec<f32>>> =
        class_texts.iter().map(|t| t.as_ref().map(|t| normalized(t.as_ref()))).collect();
    for p in prototypes.iter_mut() {
        let Some(v) = votes.iter().find(|v| v.id == p.id) else { continue };
        let mut dir = vec![0.0f32; p.embedding.len()];
        for (t, &w) in texts.iter().zip(&v.votes) {
            if let Some(t) = t.as_ref().filter(|_| w > 0.0) {
                dir.iter_mut().zip(t).for_each(|(d, x)| *d += w * x);
            }
        }
        add_direction(p, &dir, weight);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10×10 view with instance 1 in columns 0–3 and instance 2 in columns 6–9.
    fn two_instances() -> Vec<u32> {
        (0..100)
            .map(|i| match i % 10 {
                0..=3 => 1,
                6..=9 => 2,
                _ => 0,
            })
            .collect()
    }

    fn view<'a>(ids: &'a [u32], boxes: &'a [DetectedBox]) -> ViewDetections<'a> {
        ViewDetections { ids, width: 10, height: 10, boxes }
    }

    #[test]
    fn a_box_votes_for_the_instances_it_holds_by_its_score_and_fit() {
        let ids = two_instances();
        let boxes = [DetectedBox { class: 3, score: 0.8, bbox: [0.0, 0.0, 4.0, 10.0] }];
        let votes = class_votes(&[view(&ids, &boxes)], 5, 1);
        assert_eq!(votes.len(), 2);
        assert_eq!((votes[0].id, votes[0].best()), (1, Some((3, 0.8))));
        assert_eq!(votes[1].best(), None, "a box off instance 2 gives it nothing");
        // A loose box: the instance fills 4 of its 5 columns, IoU 0.8.
        let loose = [DetectedBox { class: 3, score: 0.8, bbox: [0.0, 0.0, 5.0, 10.0] }];
        let votes = class_votes(&[view(&ids, &loose)], 5, 1);
        assert!((votes[0].votes[3] - 0.64).abs() < 1e-6, "{:?}", votes[0].votes);
    }

    #[test]
    fn the_parts_of_one_object_share_its_box() {
        // Clustering cut the object in columns 0–3 into two parts; the wall (3) runs beyond.
        let ids: Vec<u32> = (0..100)
            .map(|i| match i % 10 {
                0 | 1 => 1,
                2 | 3 => 2,
                _ => 3,
            })
            .collect();
        let boxes = [DetectedBox { class: 0, score: 0.5, bbox: [0.0, 0.0, 4.0, 10.0] }];
        let votes = class_votes(&[view(&ids, &boxes)], 1, 1);
        assert_eq!(votes.iter().map(|v| v.votes[0]).collect::<Vec<_>>(), [0.5, 0.5, 0.0]);
    }

    #[test]
    fn views_weigh_by_how_much_of_the_instance_they_see() {
        let big = two_instances();
        // A second view sees a quarter of instance 1's pixels and a wrong class there.
        let small: Vec<u32> = (0..100).map(|i| u32::from(i % 10 < 4 && i < 25)).collect();
        let right = [DetectedBox { class: 0, score: 1.0, bbox: [0.0, 0.0, 4.0, 10.0] }];
        let wrong = [DetectedBox { class: 1, score: 1.0, bbox: [0.0, 0.0, 4.0, 3.0] }];
        let votes = class_votes(&[view(&big, &right), view(&small, &wrong)], 2, 1);
        let v = &votes[0];
        assert_eq!(v.views, 2);
        assert!(v.votes[0] > 3.0 * v.votes[1], "{:?}", v.votes);
        // Views under the minimum pixel count do not vote.
        let votes = class_votes(&[view(&big, &right), view(&small, &wrong)], 2, 20);
        assert_eq!((votes[0].views, votes[0].votes[1]), (1, 0.0));
    }

    #[test]
    fn votes_move_a_prototype_toward_usable_classes_only() {
        let p = |e: Vec<f32>| InstancePrototype { id: 1, embedding: e, gaussians: 10 };
        let votes = [ClassVotes { id: 1, votes: vec![0.5, 0.5], views: 1 }];
        let texts = [Some(vec![0.0, 1.0, 0.0]), None];
        let mut moved = [p(vec![1.0, 0.0, 0.0])];
        fuse_votes(&mut moved, &votes, &texts, 2.0);
        let e = &moved[0].embedding;
        assert!((e[0] - e[1]).abs() < 1e-6 && e[2] == 0.0, "{e:?}");
        let mut weak = [p(vec![1.0, 0.0, 0.0])];
        let few = [ClassVotes { id: 1, votes: vec![0.1, 0.0], views: 1 }];
        fuse_votes(&mut weak, &few, &texts, 2.0);
        assert!(weak[0].embedding[0] > 0.9, "a weak vote moves little");
    }
}
