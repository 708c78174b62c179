//! Walks [`InsSplatNet`] module by module, in the same order and with the same arithmetic as
//! its `forward`, emitting ONNX nodes with the module weights as initializers. Every op is
//! one ONNX Runtime's CPU provider runs natively (MatMul, Add, Mul, LayerNormalization,
//! Softmax, Conv, ConvTranspose, Erf, Reshape, Transpose, Concat, Slice, Split, Squeeze,
//! Shape, Expand, Exp, Softplus, Sigmoid, Identity; ReduceMean for pooled keys; in an int8
//! file also DynamicQuantizeLinear, MatMulInteger and Cast; Resize for the position embedding;
//! with the image encoder, grouped and `SAME_UPPER` Conv, Clip for ReLU6, Div, and Resize
//! (nearest) for its tokens).
//! The view count and the image's height and width stay symbolic: the patch grid ([`Sizes`])
//! is read from the images' Shape, and the position embedding is resampled to it by `Resize`
//! (linear, half-pixel), as [`InsSplatNet::position_embedding`] does.

use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::nn::{LayerNorm, Linear, PaddingConfig2d};
use inssplat_proto::signature as sig;

use super::ExportError;
use super::graph::{Dim, Graph, attr_float, attr_int, attr_ints, attr_string};
use crate::model::efficientnet::{self, EfficientNetLite0};
use crate::model::{
    Block, CameraHead, DenseDecoder, GAUSSIAN_AFFINE_CHANNELS, InsSplatNet, LN_EPS, ModelConfig,
    OUT_INSTANCE, SH_C0, encoder, gaussian_affine,
};

const END: i64 = i64::MAX;

fn linear(g: &mut Graph, hint: &str, m: &Linear, x: &str) -> Result<String, ExportError> {
    let y = if g.int8 {
        g.int8_matmul(&format!("{hint}.weight"), m.weight.val(), x)?
    } else {
        let w = g.param(&format!("{hint}.weight"), m.weight.val())?;
        g.op("MatMul", &[x, &w], vec![])
    };
    match &m.bias {
        Some(b) => {
            let b = g.param(&format!("{hint}.bias"), b.val())?;
            Ok(g.op("Add", &[&y, &b], vec![]))
        }
        None => Ok(y),
    }
}

fn layer_norm(g: &mut Graph, hint: &str, m: &LayerNorm, x: &str) -> Result<String, ExportError> {
    let gamma = g.param(&format!("{hint}.gamma"), m.gamma.val())?;
    let mut inputs = vec![x.to_string(), gamma];
    if let Some(b) = &m.beta {
        inputs.push(g.param(&format!("{hint}.beta"), b.val())?);
    }
    let refs: Vec<&str> = inputs.iter().map(String::as_str).collect();
    Ok(g.op(
        "LayerNormalization",
        &refs,
        vec![attr_int("axis", -1), attr_float("epsilon", LN_EPS as f32)],
    ))
}

/// A convolution padded by half its kernel (the decoder's), or as TensorFlow's `SAME` (the
/// encoder's, which is ONNX's `SAME_UPPER`: a stride-2 layer pads less before than after).
fn conv(g: &mut Graph, hint: &str, m: &Conv2d, x: &str) -> Result<String, ExportError> {
    let w = g.param(&format!("{hint}.weight"), m.weight.val())?;
    let b = g.param(
        &format!("{hint}.bias"),
        m.bias.as_ref().ok_or(ExportError::Unsupported("conv without bias"))?.val(),
    )?;
    let [kh, kw] = m.kernel_size;
    let padding = match m.padding {
        PaddingConfig2d::Same => attr_string("auto_pad", "SAME_UPPER"),
        _ => {
            let (ph, pw) = ((kh / 2) as i64, (kw / 2) as i64);
            attr_ints("pads", &[ph, pw, ph, pw])
        }
    };
    let mut attrs = vec![
        attr_ints("kernel_shape", &[kh as i64, kw as i64]),
        padding,
        attr_ints("strides", &[m.stride[0] as i64, m.stride[1] as i64]),
    ];
    if m.groups != 1 {
        attrs.push(attr_int("group", m.groups as i64));
    }
    Ok(g.op("Conv", &[x, &w, &b], attrs))
}

/// ReLU6, as `Clip` to [0, 6].
fn relu6(g: &mut Graph, x: &str) -> String {
    let (low, high) = (g.scalar(0.0), g.scalar(6.0));
    g.op("Clip", &[x, &low, &high], vec![])
}

/// The folded encoder's `features` of `images` (`[N, 3, H, W]` in [0, 1]): the maps at
/// strides 2 to 32.
fn encoder(g: &mut Graph, m: &EfficientNetLite0, images: &str) -> Result<Vec<String>, ExportError> {
    let (mean, std) = (g.scalar(efficientnet::MEAN), g.scalar(efficientnet::STD));
    let x = g.op("Sub", &[images, &mean], vec![]);
    let x = g.op("Div", &[&x, &std], vec![]);
    let x = conv(g, "encoder.conv_stem", &m.conv_stem, &x)?;
    let mut x = relu6(g, &x);
    let taps = efficientnet::taps();
    let mut features = Vec::with_capacity(taps.len());
    for (i, block) in m.blocks.iter().enumerate() {
        let hint = format!("encoder.blocks.{i}");
        let mut y = x.clone();
        if let Some(expand) = &block.expand_conv {
            let e = conv(g, &format!("{hint}.expand_conv"), expand, &y)?;
            y = relu6(g, &e);
        }
        let d = conv(g, &format!("{hint}.depthwise_conv"), &block.depthwise_conv, &y)?;
        let d = relu6(g, &d);
        let p = conv(g, &format!("{hint}.project_conv"), &block.project_conv, &d)?;
        x = if block.residual { g.op("Add", &[&p, &x], vec![]) } else { p };
        if taps.contains(&i) {
            features.push(x.clone());
        }
    }
    Ok(features)
}

/// `encoder::tokens`: the token levels repeated to the stride-8 grid (nearest, floor, as
/// burn's), concatenated and laid out `[N, tokens, channels]`.
fn encoder_tokens(g: &mut Graph, features: &[String]) -> String {
    let first = encoder::TOKEN_LEVELS[0];
    let maps: Vec<String> = encoder::TOKEN_LEVELS
        .iter()
        .map(|&l| {
            if l == first {
                return features[l].clone();
            }
            let factor = (1 << (l - first)) as f32;
            let scales = g.f32s("scales", &[4], &[1.0, 1.0, factor, factor]);
            g.op(
                "Resize",
                &[&features[l], "", &scales],
                vec![
                    attr_string("mode", "nearest"),
                    attr_string("coordinate_transformation_mode", "asymmetric"),
                    attr_string("nearest_mode", "floor"),
                ],
            )
        })
        .collect();
    let refs: Vec<&str> = maps.iter().map(String::as_str).collect();
    let x = g.op("Concat", &refs, vec![attr_int("axis", 1)]);
    let x = g.reshape(&x, &[0, encoder::token_channels() as i64, -1]);
    g.transpose(&x, &[0, 2, 1])
}

fn conv_transpose(
    g: &mut Graph,
    hint: &str,
    m: &ConvTranspose2d,
    x: &str,
) -> Result<String, ExportError> {
    let w = g.param(&format!("{hint}.weight"), m.weight.val())?;
    let b = g.param(
        &format!("{hint}.bias"),
        m.bias.as_ref().ok_or(ExportError::Unsupported("deconv without bias"))?.val(),
    )?;
    let [kh, kw] = m.kernel_size;
    let attrs = vec![
        attr_ints("kernel_shape", &[kh as i64, kw as i64]),
        attr_ints("strides", &[m.stride[0] as i64, m.stride[1] as i64]),
    ];
    Ok(g.op("ConvTranspose", &[x, &w, &b], attrs))
}

/// `KeyPooling::apply` on `t`, `[1, heads, views·(1 + rows·columns), head_dim]`, for a network
/// with [`ModelConfig::global_kv_pool`] `pool` (views and grid symbolic, from `sizes`).
fn pool_keys(g: &mut Graph, t: &str, heads: i64, hd: i64, sizes: &Sizes, pool: i64) -> String {
    use Dim::{Const as C, Tensor as T};
    let t = g.reshape_to(t, &[C(heads), T(&sizes.views), C(-1), C(hd)]);
    let camera = g.slice(&t, &[0], &[1], &[2]);
    let patches = g.slice(&t, &[1], &[END], &[2]);
    let (qh, qw) = (sizes.pooled[0].as_str(), sizes.pooled[1].as_str());
    let patches = g.reshape_to(&patches, &[C(heads), C(-1), T(qh), C(pool), T(qw), C(pool), C(hd)]);
    let pooled =
        g.op("ReduceMean", &[&patches], vec![attr_ints("axes", &[3, 5]), attr_int("keepdims", 0)]);
    let pooled = g.reshape_to(&pooled, &[C(heads), T(&sizes.views), C(-1), C(hd)]);
    let joined = g.op("Concat", &[&camera, &pooled], vec![attr_int("axis", 2)]);
    g.reshape(&joined, &[1, heads, -1, hd])
}

/// One transformer layer on `x`: `[batch, seq, dim]` (batch and seq may be symbolic); a
/// global layer of a network with [`ModelConfig::global_kv_pool`] passes the sizes and pool.
fn block(
    g: &mut Graph,
    hint: &str,
    m: &Block,
    x: &str,
    dim: usize,
    pooling: Option<(&Sizes, usize)>,
) -> Result<String, ExportError> {
    let heads = m.heads as i64;
    let hd = (dim / m.heads) as i64;
    let h = layer_norm(g, &format!("{hint}.norm1"), &m.norm1, x)?;
    let qkv = linear(g, &format!("{hint}.qkv"), &m.qkv, &h)?;
    let qkv = g.reshape(&qkv, &[0, 0, 3, heads, hd]);
    let qkv = g.transpose(&qkv, &[2, 0, 3, 1, 4]);
    let parts = g.op_n("Split", &[&qkv], 3, vec![attr_int("axis", 0)]);
    let axis0 = g.i64s(&[0]);
    let q = g.op("Squeeze", &[&parts[0], &axis0], vec![]);
    let k = g.op("Squeeze", &[&parts[1], &axis0], vec![]);
    let v = g.op("Squeeze", &[&parts[2], &axis0], vec![]);
    let (k, v) = match pooling {
        Some((sizes, pool)) => {
            let pool = |g: &mut Graph, t: &str| pool_keys(g, t, heads, hd, sizes, pool as i64);
            (pool(g, &k), pool(g, &v))
        }
        None => (k, v),
    };
    let scale = g.scalar(1.0 / (hd as f32).sqrt());
    let q = g.op("Mul", &[&q, &scale], vec![]);
    let kt = g.transpose(&k, &[0, 1, 3, 2]);
    let scores = g.op("MatMul", &[&q, &kt], vec![]);
    let probs = g.op("Softmax", &[&scores], vec![attr_int("axis", -1)]);
    let ctx = g.op("MatMul", &[&probs, &v], vec![]);
    let ctx = g.transpose(&ctx, &[0, 2, 1, 3]);
    let ctx = g.reshape(&ctx, &[0, 0, dim as i64]);
    let a = linear(g, &format!("{hint}.proj"), &m.proj, &ctx)?;
    let x = g.op("Add", &[x, &a], vec![]);
    let h = layer_norm(g, &format!("{hint}.norm2"), &m.norm2, &x)?;
    let h = linear(g, &format!("{hint}.fc1"), &m.fc1, &h)?;
    let h = g.gelu(&h);
    let h = linear(g, &format!("{hint}.fc2"), &m.fc2, &h)?;
    Ok(g.op("Add", &[&x, &h], vec![]))
}

/// The run-time sizes of the input, each a 1-D int64 tensor of one element: the view count,
/// the patch grid's rows and columns, and (with pooled global keys) the pooled grid's.
struct Sizes {
    views: String,
    grid: [String; 2],
    pooled: [String; 2],
}

impl Sizes {
    fn of_images(g: &mut Graph, c: &ModelConfig) -> Self {
        let shape = g.op("Shape", &[sig::INPUT_IMAGES.name], vec![]);
        let views = g.slice(&shape, &[0], &[1], &[0]);
        let mut side = |axis: i64, divisor: usize| {
            let pixels = g.slice(&shape, &[axis], &[axis + 1], &[0]);
            let d = g.i64s(&[divisor as i64]);
            g.op("Div", &[&pixels, &d], vec![])
        };
        let grid = [side(2, c.patch), side(3, c.patch)];
        let m = c.size_multiple();
        let pooled = [side(2, m), side(3, m)];
        Self { views, grid, pooled }
    }
}

/// Token embedding, as `InsSplatNet::embed`, of the pixels or of the encoder's `features`.
/// Returns (centred images, tokens `[N, S, dim]`).
fn embed(
    g: &mut Graph,
    net: &InsSplatNet,
    features: Option<&[String]>,
    sizes: &Sizes,
) -> Result<(String, String), ExportError> {
    use Dim::{Const as C, Tensor as T};
    let c = net.config();
    let (p, d) = (c.patch as i64, c.dim);
    let [gh, gw] = [sizes.grid[0].as_str(), sizes.grid[1].as_str()];
    let half = g.scalar(0.5);
    let centred = g.op("Sub", &[sig::INPUT_IMAGES.name, &half], vec![]);
    let x = match features {
        Some(features) => encoder_tokens(g, features),
        None => {
            let x = g.reshape_to(&centred, &[C(-1), C(3), T(gh), C(p), T(gw), C(p)]);
            let x = g.transpose(&x, &[0, 2, 4, 1, 3, 5]);
            g.reshape(&x, &[0, -1, 3 * p * p])
        }
    };
    let x = linear(g, "patch_embed", &net.patch_embed, &x)?;
    let pos = position_embedding(g, net, c, sizes)?;
    let mut x = g.op("Add", &[&x, &pos], vec![]);
    if let Some(embed) = &net.ray_embed {
        let rays = linear(g, "ray_embed", embed, sig::INPUT_RAYS.name)?;
        x = g.op("Add", &[&x, &rays], vec![]);
    }
    let cams = net.camera_tokens.val();
    let cam0 = g.weight("camera_token.reference", cams.clone().narrow(0, 0, 1), &[1, 1, d])?;
    let cam1 = g.weight("camera_token.other", cams.narrow(0, 1, 1), &[1, 1, d])?;
    let reference = g.param("reference_embed", net.reference_embed.val())?;
    let first = g.slice(&x, &[0], &[1], &[0]);
    let first = g.op("Add", &[&first, &reference], vec![]);
    let first = g.op("Concat", &[&cam0, &first], vec![attr_int("axis", 1)]);
    let rest = g.slice(&x, &[1], &[END], &[0]);
    let others = g.op("Shape", &[&rest], vec![attr_int("start", 0), attr_int("end", 1)]);
    let tail = g.i64s(&[1, d as i64]);
    let target = g.op("Concat", &[&others, &tail], vec![attr_int("axis", 0)]);
    let rest_cam = g.op("Expand", &[&cam1, &target], vec![]);
    let rest = g.op("Concat", &[&rest_cam, &rest], vec![attr_int("axis", 1)]);
    let tokens = g.op("Concat", &[&first, &rest], vec![attr_int("axis", 0)]);
    Ok((centred, tokens))
}

/// `InsSplatNet::position_embedding` at the run-time grid: the square `[1, dim, g, g]`
/// resampled by `Resize` (linear, half-pixel centres; the same size is the identity).
fn position_embedding(
    g: &mut Graph,
    net: &InsSplatNet,
    c: &ModelConfig,
    sizes: &Sizes,
) -> Result<String, ExportError> {
    use Dim::{Const as C, Tensor as T};
    let (side, d) = (c.grid() as i64, c.dim as i64);
    let pos = g.param("pos_embed", net.pos_embed.val())?;
    let square = g.reshape(&pos, &[1, side, side, d]);
    let square = g.transpose(&square, &[0, 3, 1, 2]);
    let target = g.shape_of(&[C(1), C(d), T(&sizes.grid[0]), T(&sizes.grid[1])]);
    let resized = g.op(
        "Resize",
        &[&square, "", "", &target],
        vec![
            attr_string("mode", "linear"),
            attr_string("coordinate_transformation_mode", "half_pixel"),
        ],
    );
    let resized = g.transpose(&resized, &[0, 2, 3, 1]);
    Ok(g.reshape(&resized, &[1, -1, d]))
}

fn camera_head(
    g: &mut Graph,
    m: &CameraHead,
    tokens: &str,
    c: &ModelConfig,
) -> Result<(), ExportError> {
    let x = layer_norm(g, "camera_head.norm", &m.norm, tokens)?;
    let x = linear(g, "camera_head.fc1", &m.fc1, &x)?;
    let x = g.gelu(&x);
    let raw = linear(g, "camera_head.fc2", &m.fc2, &x)?;
    let fov = g.slice(&raw, &[7], &[9], &[1]);
    let fov = g.op("Sigmoid", &[&fov], vec![]);
    let fov_scale = g.scalar((2.0 * c.fov_base) as f32);
    let fov = g.op("Mul", &[&fov, &fov_scale], vec![]);
    let identity = g.f32s("identity_pose", &[1, 7], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
    let rest = g.slice(&raw, &[1, 0], &[END, 7], &[0, 1]);
    let rest = g.op("Add", &[&rest, &identity], vec![]);
    let pose = g.op("Concat", &[&identity, &rest], vec![attr_int("axis", 0)]);
    g.op_into("Concat", &[&pose, &fov], &[sig::OUTPUT_CAMERA.name], vec![attr_int("axis", 1)]);
    Ok(())
}

fn decoder(
    g: &mut Graph,
    m: &DenseDecoder,
    levels: &[String],
    encoded: &[String],
    centred: &str,
    c: &ModelConfig,
    sizes: &Sizes,
) -> Result<(), ExportError> {
    use Dim::{Const as C, Tensor as T};
    let refs: Vec<&str> = levels.iter().map(String::as_str).collect();
    let x = g.op("Concat", &refs, vec![attr_int("axis", 2)]);
    let x = layer_norm(g, "decoder.norm", &m.norm, &x)?;
    let x = linear(g, "decoder.fuse", &m.fuse, &x)?;
    let grid = [T(&sizes.grid[0]), T(&sizes.grid[1])];
    let x = g.reshape_to(&x, &[C(-1), grid[0], grid[1], C(c.decoder_dim as i64)]);
    let mut features: Vec<String> = Vec::with_capacity(m.skips.len());
    for (l, skip) in m.skips.iter().enumerate() {
        let input = features.last().map_or(centred, String::as_str);
        let f = conv(g, &format!("decoder.skips.{l}.encode"), &skip.encode, input)?;
        features.push(g.gelu(&f));
    }
    let mut x = g.transpose(&x, &[0, 3, 1, 2]);
    for (i, stage) in m.stages.iter().enumerate() {
        let r = conv(g, &format!("decoder.stages.{i}.refine"), &stage.refine, &x)?;
        let r = g.gelu(&r);
        let y = g.op("Add", &[&x, &r], vec![]);
        x = conv_transpose(g, &format!("decoder.stages.{i}.up"), &stage.up, &y)?;
        let level = m.stages.len() - 1 - i;
        if let (Some(skip), Some(f)) = (m.skips.get(level), features.get(level)) {
            let s = conv(g, &format!("decoder.skips.{level}.inject"), &skip.inject, f)?;
            x = g.op("Add", &[&x, &s], vec![]);
        }
        let e = level.wrapping_sub(1);
        if let (Some(skip), Some(f)) = (m.encoder_skips.get(e), encoded.get(e)) {
            let s = conv(g, &format!("decoder.encoder_skips.{e}"), skip, f)?;
            x = g.op("Add", &[&x, &s], vec![]);
        }
    }
    let x = g.op("Concat", &[&x, centred], vec![attr_int("axis", 1)]);
    let x = conv(g, "decoder.mix", &m.mix, &x)?;
    let x = g.gelu(&x);
    let raw = conv(g, "decoder.out", &m.out, &x)?;
    let split =
        g.i64s(&[1, 1, GAUSSIAN_AFFINE_CHANNELS as i64, 3, c.sem_dim as i64, OUT_INSTANCE as i64]);
    let parts = g.op_n("Split", &[&raw, &split], 6, vec![attr_int("axis", 1)]);
    let depth = g.op("Softplus", &[&parts[0]], vec![]);
    let depth_scale = g.scalar(c.depth_scale as f32);
    g.op_into("Mul", &[&depth, &depth_scale], &[sig::OUTPUT_DEPTH.name], vec![]);
    let conf = g.op("Exp", &[&parts[1]], vec![]);
    let one = g.scalar(1.0);
    g.op_into("Add", &[&conf, &one], &[sig::OUTPUT_DEPTH_CONF.name], vec![]);
    let (mul, add) = gaussian_affine(c);
    let n_aff = GAUSSIAN_AFFINE_CHANNELS;
    let mul = g.f32s("gaussian_mul", &[1, n_aff, 1, 1], &mul);
    let add = g.f32s("gaussian_add", &[1, n_aff, 1, 1], &add);
    let affine = g.op("Mul", &[&parts[2], &mul], vec![]);
    let affine = g.op("Add", &[&affine, &add], vec![]);
    let inv_c0 = g.scalar((1.0 / SH_C0) as f32);
    let skip = g.op("Mul", &[centred, &inv_c0], vec![]);
    let colour = g.op("Add", &[&parts[3], &skip], vec![]);
    g.op_into(
        "Concat",
        &[&affine, &colour],
        &[sig::OUTPUT_GAUSSIANS.name],
        vec![attr_int("axis", 1)],
    );
    g.op_into("Identity", &[&parts[4]], &[sig::OUTPUT_SEMANTIC.name], vec![]);
    g.op_into("Identity", &[&parts[5]], &[sig::OUTPUT_INSTANCE.name], vec![]);
    Ok(())
}

/// Emits the whole network into `g`, reading `images` (and `rays`, for a network that reads
/// its cameras) and writing every signature output.
pub fn network(g: &mut Graph, net: &InsSplatNet) -> Result<(), ExportError> {
    let c = net.config();
    let d = c.dim as i64;
    let sizes = Sizes::of_images(g, c);
    let features =
        net.encoder.as_ref().map(|e| encoder(g, e, sig::INPUT_IMAGES.name)).transpose()?;
    let (centred, mut x) = embed(g, net, features.as_deref(), &sizes)?;
    let mut levels = Vec::new();
    for (i, b) in net.blocks.iter().enumerate() {
        let hint = format!("blocks.{i}");
        if i % 2 == 0 {
            x = block(g, &hint, b, &x, c.dim, None)?;
        } else {
            let flat = g.reshape(&x, &[1, -1, d]);
            let y = block(g, &hint, b, &flat, c.dim, c.global_kv_pool.map(|p| (&sizes, p)))?;
            x = g.reshape_to(&y, &[Dim::Tensor(&sizes.views), Dim::Const(-1), Dim::Const(d)]);
            levels.push(g.slice(&x, &[1], &[END], &[1]));
        }
    }
    let cam = g.slice(&x, &[0], &[1], &[1]);
    let cam = g.reshape(&cam, &[-1, d]);
    camera_head(g, &net.camera_head, &cam, c)?;
    let encoded = features.as_ref().map_or(&[][..], |f| &f[..encoder::SKIP_LEVELS]);
    decoder(g, &net.decoder, &levels, encoded, &centred, c, &sizes)?;
    let (w, b) = net.sem_proj();
    let w = g.param("sem_proj.weight", w)?;
    let b = g.param("sem_proj.bias", b)?;
    g.op_into("Identity", &[&w], &[sig::OUTPUT_SEM_PROJ_WEIGHT.name], vec![]);
    g.op_into("Identity", &[&b], &[sig::OUTPUT_SEM_PROJ_BIAS.name], vec![]);
    Ok(())
}
