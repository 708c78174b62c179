//! Stage "cluster": instances found once in 3D (HDBSCAN on the merged Gaussians' instance
//! embeddings and positions), then each split into its parts apart in 3D
//! ([`inssplat_understand::cluster`]).

use inssplat_geometry::voxel::Voxelized;
use inssplat_understand::cluster::split::{SplitParams, split_disconnected};
use inssplat_understand::cluster::{ClusterError, ClusterParams, cluster_instances};

use super::stage_err;
use crate::reconstruct::PipelineError;

/// Gives every merged Gaussian its instance id (0: none).
pub fn run(
    voxelized: &mut Voxelized,
    params: &ClusterParams,
    split: Option<&SplitParams>,
) -> Result<(), PipelineError> {
    let result = (|| {
        cluster_instances(&mut voxelized.scene, params)?;
        if let Some(split) = split {
            let cell = split.cell_voxels * voxelized.report.voxel_size;
            split_disconnected(
                &voxelized.scene.means,
                &mut voxelized.scene.instance_id,
                cell,
                split,
            );
        }
        Ok::<_, ClusterError>(())
    })();
    result.map_err(|e| stage_err("cluster")(&e))
}
