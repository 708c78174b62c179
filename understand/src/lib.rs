//! inssplat-understand: what the Gaussians are. Instance clustering once in 3D (HDBSCAN on
//! instance embeddings and positions, then the split of instances into parts apart in 3D;
//! [`cluster`]), the photos' colour superpixels that the embeddings and masks snap to
//! ([`superpixel`]), the label maps' upsampling to the photos' resolution along their edges
//! ([`upsample`]), and naming: semantic prototypes, shape descriptors, the shape
//! classifier's fusion and text labels ([`label`]). Pure functions of arrays; no network,
//! no rendering.

pub mod cluster;
pub mod label;
pub mod superpixel;
pub mod upsample;
