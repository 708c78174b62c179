//! Splitting instances into their connected parts in 3D. The clustering gives two objects
//! one id when the network's embeddings do not tell them apart, even where they stand apart
//! (two chairs of a set); the position beside the embedding only weighs against that. After
//! clustering, each instance's Gaussians are joined to every Gaussian of the same id in the
//! same or a touching cell of a grid, and each part but the largest that holds at least
//! [`SplitParams::min_share`] of the instance (and [`SplitParams::min_gaussians`]) becomes an
//! instance of its own; smaller parts keep the id. The cost is one pass over the Gaussians
//! and 13 lookups per occupied cell.

use rustc_hash::FxHashMap;

/// Half of the 26 neighbouring cells (the other half joins from the other side).
const NEIGHBOURS: [[i32; 3]; 13] = [
    [1, 0, 0],
    [0, 1, 0],
    [0, 0, 1],
    [1, 1, 0],
    [1, -1, 0],
    [1, 0, 1],
    [1, 0, -1],
    [0, 1, 1],
    [0, 1, -1],
    [1, 1, 1],
    [1, 1, -1],
    [1, -1, 1],
    [1, -1, -1],
];

/// Tunables of [`split_disconnected`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitParams {
    /// Edge of the grid whose touching cells connect Gaussians, in voxel edges.
    pub cell_voxels: f32,
    /// A part needs this share of its instance's Gaussians to become an instance.
    pub min_share: f32,
    /// And at least this many Gaussians.
    pub min_gaussians: usize,
}

impl Default for SplitParams {
    fn default() -> Self {
        Self { cell_voxels: 1.0, min_share: 0.1, min_gaussians: 20 }
    }
}

/// Union–find with path halving.
struct Parts(Vec<u32>);

impl Parts {
    fn root(&mut self, mut i: u32) -> u32 {
        while self.0[i as usize] != i {
            let up = self.0[self.0[i as usize] as usize];
            self.0[i as usize] = up;
            i = up;
        }
        i
    }

    fn join(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.root(a), self.root(b));
        if ra != rb {
            self.0[ra.max(rb) as usize] = ra.min(rb);
        }
    }
}

/// Splits every instance of `ids` (per point, 0 = none) into its connected parts, as
/// [`SplitParams`] says: points of one id are connected when they fall in the same or
/// touching cells (26-neighbourhood) of a grid of edge `cell` (world units) over `means`.
/// New ids follow the largest id. Returns how many instances were added.
pub fn split_disconnected(
    means: &[[f32; 3]],
    ids: &mut [u32],
    cell: f32,
    params: &SplitParams,
) -> usize {
    assert_eq!(means.len(), ids.len(), "one id per point");
    if cell.is_nan() || cell <= 0.0 {
        return 0;
    }
    // The first point of every (id, cell); every point joins it, and it joins the firsts of
    // the touching cells.
    let mut parts = Parts((0..means.len() as u32).collect());
    let mut first: FxHashMap<(u32, [i32; 3]), u32> = FxHashMap::default();
    let mut kept = Vec::with_capacity(means.len());
    for (i, (p, &id)) in means.iter().zip(ids.iter()).enumerate() {
        if id > 0 && p.iter().all(|x| x.is_finite()) {
            let f = *first.entry((id, p.map(|x| (x / cell).floor() as i32))).or_insert(i as u32);
            parts.join(f, i as u32);
            kept.push(i as u32);
        }
    }
    for (&(id, c), &a) in &first {
        for d in NEIGHBOURS {
            if let Some(&b) = first.get(&(id, [c[0] + d[0], c[1] + d[1], c[2] + d[2]])) {
                parts.join(a, b);
            }
        }
    }
    // Every part as (id, size, root), per id largest first (ties: the lower root).
    let mut size = vec![0usize; means.len()];
    for &i in &kept {
        size[parts.root(i) as usize] += 1;
    }
    let mut list: Vec<(u32, usize, u32)> =
        (0..means.len()).filter(|&r| size[r] > 0).map(|r| (ids[r], size[r], r as u32)).collect();
    list.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(b.1.cmp(&a.1)).then(a.2.cmp(&b.2)));
    let first_new = ids.iter().copied().max().unwrap_or(0) + 1;
    let mut next = first_new;
    let mut new_id = vec![0u32; means.len()];
    for group in list.chunk_by(|a, b| a.0 == b.0) {
        let total: usize = group.iter().map(|g| g.1).sum();
        let least = ((params.min_share * total as f32).ceil() as usize).max(params.min_gaussians);
        for &(_, _, root) in group.iter().skip(1).filter(|g| g.1 >= least) {
            new_id[root as usize] = next;
            next += 1;
        }
    }
    for &i in &kept {
        let n = new_id[parts.root(i) as usize];
        if n > 0 {
            ids[i as usize] = n;
        }
    }
    (next - first_new) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line of `n` points spaced 0.1 apart from `start` along x.
    fn line(start: f32, n: usize) -> Vec<[f32; 3]> {
        (0..n).map(|i| [start + 0.1 * i as f32, 0.0, 0.0]).collect()
    }

    #[test]
    fn an_instance_in_two_places_becomes_two_and_a_stray_point_keeps_its_id() {
        // Id 1: 40 points at x 0–3.9 and 30 at x 10–12.9 (apart), and one stray at x 20;
        // id 2: 25 points next to the first part of id 1 (touching it, another id).
        let mut means = line(0.0, 40);
        means.extend(line(10.0, 30));
        means.push([20.0, 0.0, 0.0]);
        means.extend(line(0.05, 25));
        let mut ids: Vec<u32> = [vec![1; 40], vec![1; 30], vec![1], vec![2; 25]].concat();
        let params = SplitParams { cell_voxels: 1.0, min_share: 0.1, min_gaussians: 5 };
        assert_eq!(split_disconnected(&means, &mut ids, 0.15, &params), 1);
        assert!(ids[..40].iter().all(|&i| i == 1), "the largest part keeps the id");
        assert!(
            ids[40..70].iter().all(|&i| i == 3),
            "the far part is instance 3: {:?}",
            &ids[40..70]
        );
        assert_eq!(ids[70], 1, "a part under min_share keeps the id");
        assert!(ids[71..].iter().all(|&i| i == 2), "another id touching it is not merged");
    }

    #[test]
    fn a_connected_instance_and_a_cell_of_zero_change_nothing() {
        let means = line(0.0, 50);
        let mut ids = vec![1; 50];
        ids[0] = 0;
        let before = ids.clone();
        assert_eq!(split_disconnected(&means, &mut ids, 0.15, &SplitParams::default()), 0);
        assert_eq!(ids, before);
        let mut means = line(0.0, 30);
        means.extend(line(100.0, 30));
        let mut ids = vec![1; 60];
        assert_eq!(split_disconnected(&means, &mut ids, 0.0, &SplitParams::default()), 0);
        assert!(ids.iter().all(|&i| i == 1));
        // Parts of equal size: the one holding the lower index keeps the id.
        assert_eq!(
            split_disconnected(
                &means,
                &mut ids,
                0.15,
                &SplitParams { min_gaussians: 5, ..SplitParams::default() }
            ),
            1
        );
        assert!(ids[..30].iter().all(|&i| i == 1) && ids[30..].iter().all(|&i| i == 2));
    }
}
