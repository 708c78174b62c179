//! Dataset splits and their seeds. `train`, `val` and `test` draw scene seeds from disjoint
//! ranges of [`SPLIT_STRIDE`] seeds each, so no scene appears in two splits whatever the
//! counts and offsets. Test scenes also carry the evaluation split of docs/DATASET.md: nested
//! context sets for 2/4/8/16 views spread along the camera path and the remaining frames as
//! targets (novel views between and beside the inputs).

use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

use inssplat_proto::dataset::EvalSplit;

use super::SynthError;

/// Seeds per split.
pub const SPLIT_STRIDE: u64 = 1 << 40;

/// View counts the evaluation split defines context sets for.
pub const CONTEXT_VIEWS: [usize; 4] = [2, 4, 8, 16];

#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// Seed of scene `index` of this split.
    pub fn seed(self, index: u64) -> Result<u64, SynthError> {
        if index >= SPLIT_STRIDE {
            return Err(SynthError::Config(format!(
                "scene index {index} is beyond the {SPLIT_STRIDE} seeds of a split"
            )));
        }
        Ok(self as u64 * SPLIT_STRIDE + index)
    }

    /// The split a seed belongs to.
    pub fn of_seed(seed: u64) -> Option<Split> {
        Split::ALL.get((seed / SPLIT_STRIDE) as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Split {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Split::ALL
            .into_iter()
            .find(|x| x.name() == s)
            .ok_or_else(|| format!("`{s}` is not a split (train, val, test)"))
    }
}

/// Context sets (nested, spread evenly over the path) and targets for `frames` frames. The
/// largest context set is the largest of [`CONTEXT_VIEWS`] that leaves at least one target.
pub fn eval_split(frames: usize) -> Option<EvalSplit> {
    let largest = CONTEXT_VIEWS.iter().copied().filter(|&v| v < frames).max()?;
    let spread: Vec<usize> = (0..largest)
        .map(|i| ((i as f64 * (frames - 1) as f64 / (largest - 1) as f64).round()) as usize)
        .collect();
    let mut context = BTreeMap::new();
    let mut set = spread.clone();
    for &v in CONTEXT_VIEWS.iter().rev().filter(|&&v| v <= largest) {
        while set.len() > v {
            // Halve by keeping every other frame: the smaller set stays inside the larger one.
            set = set.iter().copied().step_by(2).collect();
        }
        context.insert(v.to_string(), set.clone());
    }
    let target = (0..frames).filter(|i| !spread.contains(i)).collect();
    Some(EvalSplit { context, target })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_are_disjoint_per_split() {
        let a = Split::Train.seed(SPLIT_STRIDE - 1).unwrap();
        let b = Split::Val.seed(0).unwrap();
        assert!(a < b);
        assert_eq!(Split::of_seed(b), Some(Split::Val));
        assert_eq!(Split::of_seed(Split::Test.seed(5).unwrap()), Some(Split::Test));
        assert!(Split::Train.seed(SPLIT_STRIDE).is_err());
        assert_eq!("val".parse::<Split>(), Ok(Split::Val));
    }

    #[test]
    fn eval_split_is_nested_and_disjoint() {
        for frames in [3, 5, 9, 12, 17, 24] {
            let e = eval_split(frames).unwrap();
            let sizes: Vec<usize> = e.context.values().map(Vec::len).collect();
            for (k, v) in &e.context {
                assert_eq!(k.parse::<usize>().unwrap(), v.len(), "{frames}: {e:?}");
                assert!(v.iter().all(|i| !e.target.contains(i) && *i < frames));
                let mut d = v.clone();
                d.dedup();
                assert_eq!(d.len(), v.len(), "distinct frames");
            }
            let sets: Vec<&Vec<usize>> =
                CONTEXT_VIEWS.iter().filter_map(|v| e.context.get(&v.to_string())).collect();
            for w in sets.windows(2) {
                assert!(w[0].iter().all(|i| w[1].contains(i)), "nested: {e:?}");
            }
            assert!(!e.target.is_empty(), "{frames} frames: {sizes:?}");
        }
        let e = eval_split(24).unwrap();
        assert_eq!(e.context["16"].len(), 16);
        assert_eq!(e.target.len(), 8);
        assert!(eval_split(2).is_none() || eval_split(2).unwrap().context.is_empty());
    }
}
