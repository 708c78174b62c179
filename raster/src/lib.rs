//! inssplat-raster: the 3D Gaussian rasterizer and nothing else. The differentiable CPU tile
//! rasterizer (forward and hand-written backward, any channel count), the wgpu forward
//! rasterizer for serving (feature `gpu`), rendering a [`inssplat_proto::GaussianScene`]'s
//! colours, instance ids and label maps ([`masks`]), and the fill of what no Gaussian covers
//! in a new view ([`fill`]). It knows nothing of networks, clustering or HTTP.

pub mod fill;
pub mod masks;
pub mod render;
