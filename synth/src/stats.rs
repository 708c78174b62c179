//! Dataset statistics: how often each category appears, instances per scene, the share of
//! pixels per class, and the share of scenes with two or more instances of one category
//! (the case instance-aware reconstruction exists for). Computed from scenes as written, so
//! the CLI and the tests measure what the trainer will read.

use std::collections::BTreeMap;
use std::fmt;

use inssplat_proto::dataset::Scene;

/// Labels of the room shell; they never count as repeated categories.
pub const SHELL_LABELS: [&str; 3] = ["wall", "floor", "ceiling"];

/// Pixel class of id 0.
pub const BACKGROUND: &str = "background";

#[derive(Debug, Clone, Default, PartialEq)]
pub struct DatasetStats {
    pub scenes: usize,
    pub frames: usize,
    /// Instances per label over all scenes.
    pub category_counts: BTreeMap<String, usize>,
    /// Object instances (shell excluded) per scene, in the order added.
    pub instances_per_scene: Vec<usize>,
    /// Pixels per class (label, or [`BACKGROUND`]).
    pub pixels: BTreeMap<String, u64>,
    pub scenes_with_repeat: usize,
}

impl DatasetStats {
    pub fn add(&mut self, scene: &Scene) {
        self.scenes += 1;
        self.frames += scene.frames.len();
        let mut per_label: BTreeMap<&str, usize> = BTreeMap::new();
        for inst in &scene.instances {
            *self.category_counts.entry(inst.label.clone()).or_default() += 1;
            if !SHELL_LABELS.contains(&inst.label.as_str()) {
                *per_label.entry(inst.label.as_str()).or_default() += 1;
            }
        }
        self.instances_per_scene.push(per_label.values().sum());
        if per_label.values().any(|&n| n >= 2) {
            self.scenes_with_repeat += 1;
        }
        // id → label lookup over the 16-bit range.
        let mut label_of: Vec<&str> = vec![BACKGROUND; 1 << 16];
        for inst in &scene.instances {
            if let Some(slot) = label_of.get_mut(inst.id as usize) {
                *slot = inst.label.as_str();
            }
        }
        let mut counts = vec![0u64; 1 << 16];
        for f in &scene.frames {
            for &id in f.instances.iter().flatten() {
                counts[id as usize] += 1;
            }
        }
        for (id, &n) in counts.iter().enumerate().filter(|(_, n)| **n > 0) {
            *self.pixels.entry(label_of[id].to_string()).or_default() += n;
        }
    }

    pub fn merge(&mut self, other: DatasetStats) {
        self.scenes += other.scenes;
        self.frames += other.frames;
        for (k, v) in other.category_counts {
            *self.category_counts.entry(k).or_default() += v;
        }
        self.instances_per_scene.extend(other.instances_per_scene);
        for (k, v) in other.pixels {
            *self.pixels.entry(k).or_default() += v;
        }
        self.scenes_with_repeat += other.scenes_with_repeat;
    }

    /// Share of scenes with ≥ 2 instances of one (non-shell) category.
    pub fn repeat_share(&self) -> f64 {
        if self.scenes == 0 { 0.0 } else { self.scenes_with_repeat as f64 / self.scenes as f64 }
    }

    /// Number of distinct object categories (shell labels excluded).
    pub fn categories(&self) -> usize {
        self.category_counts.keys().filter(|k| !SHELL_LABELS.contains(&k.as_str())).count()
    }

    pub fn mean_instances(&self) -> f64 {
        let n = self.instances_per_scene.len().max(1) as f64;
        self.instances_per_scene.iter().sum::<usize>() as f64 / n
    }

    /// (class, share of all pixels), largest first.
    pub fn pixel_shares(&self) -> Vec<(String, f64)> {
        let total = self.pixels.values().sum::<u64>().max(1) as f64;
        let mut v: Vec<(String, f64)> =
            self.pixels.iter().map(|(k, &n)| (k.clone(), n as f64 / total)).collect();
        v.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
        v
    }
}

impl fmt::Display for DatasetStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (min, max) = (
            self.instances_per_scene.iter().min().copied().unwrap_or(0),
            self.instances_per_scene.iter().max().copied().unwrap_or(0),
        );
        writeln!(f, "scenes: {}, frames: {}", self.scenes, self.frames)?;
        writeln!(
            f,
            "instances per scene: mean {:.1}, min {min}, max {max}",
            self.mean_instances()
        )?;
        writeln!(
            f,
            "scenes with >= 2 instances of one category: {:.1}% ({} of {})",
            100.0 * self.repeat_share(),
            self.scenes_with_repeat,
            self.scenes
        )?;
        writeln!(f, "categories: {}", self.categories())?;
        let mut cats: Vec<(&String, &usize)> = self.category_counts.iter().collect();
        cats.sort_by(|a, b| b.1.cmp(a.1).then_with(|| a.0.cmp(b.0)));
        for (label, n) in cats {
            writeln!(f, "  {label:<18} {n:>7} instances")?;
        }
        writeln!(f, "share of pixels per class:")?;
        for (label, share) in self.pixel_shares() {
            writeln!(f, "  {label:<18} {:>6.2}%", 100.0 * share)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use inssplat_proto::camera::{Camera, Intrinsics};
    use inssplat_proto::dataset::{Frame, InstanceLabel};

    #[test]
    fn counts_repeats_pixels_and_ignores_the_shell() {
        let k = Intrinsics::from_fov_y(2, 2, 1.0);
        let cam = Camera::look_at(k, glam::Vec3::ZERO, glam::Vec3::Z, glam::Vec3::Y);
        let label = |id, l: &str| InstanceLabel { id, label: l.into() };
        let frame = |ids: Vec<u16>| Frame {
            camera: cam,
            rgb: vec![0; 12],
            depth: None,
            instances: Some(ids),
        };
        let scene = |instances, ids| Scene {
            dir: Default::default(),
            instances,
            frames: vec![frame(ids)],
            eval: None,
            depth_unit_m: 0.001,
        };
        let mut s = DatasetStats::default();
        s.add(&scene(
            vec![label(1, "chair"), label(2, "chair"), label(3, "lamp")],
            vec![0, 1, 2, 3],
        ));
        s.add(&scene(vec![label(1, "wall"), label(2, "wall"), label(3, "lamp")], vec![1, 1, 2, 3]));
        assert_eq!(s.scenes_with_repeat, 1, "two walls are not a repeated category");
        assert_eq!(s.repeat_share(), 0.5);
        assert_eq!(s.categories(), 2);
        assert_eq!(s.instances_per_scene, vec![3, 1]);
        assert_eq!(s.pixels["wall"], 3);
        assert_eq!(s.pixels[BACKGROUND], 1);
        let text = s.to_string();
        assert!(text.contains("50.0%") && text.contains("chair"), "{text}");
    }
}
