//! What a user should know about a reconstruction's inputs, in words: photos sent twice,
//! photos that registration could not link or barely could, photos with too little texture to
//! find keypoints in. Each names the view; none stops the reconstruction.

use inssplat_proto::api::{CameraOut, Placement};

use crate::reconstruct::Reconstruction;

/// A registered view with fewer matches than this fitting its pose is weakly placed.
pub const FEW_MATCHES: usize = 20;
/// A photo with fewer keypoints than this has too little texture to register well.
pub const FEW_KEYPOINTS: usize = 30;

/// The warnings of `rec`, whose cameras are `cameras` (as [`crate::output::cameras_out`] gives
/// them), one sentence each.
pub fn warnings(rec: &Reconstruction, cameras: &[CameraOut]) -> Vec<String> {
    let mut out = Vec::new();
    for (j, b) in rec.views.iter().enumerate() {
        if let Some(i) = rec.views[..j].iter().position(|a| a.rgb == b.rgb) {
            out.push(format!("views {i} and {j} are the same photo: the second adds no viewpoint"));
        }
    }
    for c in cameras {
        let v = c.view;
        let fit = c.fit.as_ref();
        if let Some(f) = fit.filter(|f| f.keypoints < FEW_KEYPOINTS) {
            out.push(format!(
                "view {v}: {} keypoints found: the photo has too little texture to register well",
                f.keypoints
            ));
        }
        match c.placement {
            Some(Placement::Continued | Placement::CameraHead) if fit.is_some() => {
                out.push(format!(
                    "view {v}: no keypoint match links it to view 0's photos (too little overlap, or it shows something else): its pose is a guess"
                ));
            }
            Some(Placement::Registered) => {
                if let Some(f) = fit.filter(|f| f.matches < FEW_MATCHES) {
                    out.push(format!(
                        "view {v}: only {} matches fit its pose: a photo with more overlap would place it surely",
                        f.matches
                    ));
                }
            }
            _ => {}
        }
    }
    out
}
