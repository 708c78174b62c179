//! The network's GELU, `x · Φ(x)` (exact, not the tanh form), computed on the CPU across the
//! cores. burn's Flex backend evaluates an element-wise op on the calling thread, with one
//! libm `erf` per element forward and one `erf` and one `exp` backward; at 4 views the
//! network runs about 10 M of them a step, one core busy and the other idle. Here the
//! forward and the backward run in parallel chunks and share one `exp` per element:
//! Φ(x) = ½(1 + erf(x/√2)) with the erf of Abramowitz & Stegun 7.1.26 (absolute error ≤
//! 1.5·10⁻⁷, what a float32 holds), whose exp(−x²/2) is also the density that the
//! derivative Φ(x) + x·φ(x) needs.
//!
//! On an autodiff Flex device the op enters the graph with its own backward (as
//! [`crate::render_op`] does); on a plain Flex device it is the forward alone; on any other
//! device (the wgpu backend) it is burn's `gelu`.

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::{
    BalancedCheckpointing, CheckpointStrategy, NoCheckpointing,
};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, DispatchKindConversion, DispatchTensor, Flex, GradientCheckpointingStrategy,
    TensorMetadata,
};
use burn::prelude::*;
use burn::tensor::DType;
use rayon::prelude::*;

/// Elements a parallel task takes: large enough that a task outweighs its dispatch.
const CHUNK: usize = 16 * 1024;

/// 1/√2 and 1/√(2π).
const FRAC_1_SQRT_2: f32 = std::f32::consts::FRAC_1_SQRT_2;
const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;

/// Φ(x) and φ(x), the standard normal's distribution and density at `x`.
#[inline(always)]
fn normal_cdf_pdf(x: f32) -> (f32, f32) {
    let density = (-0.5 * x * x).exp();
    let t = 1.0 / (1.0 + 0.327_591_1 * FRAC_1_SQRT_2 * x.abs());
    let poly = t
        * (0.254_829_6
            + t * (-0.284_496_7 + t * (1.421_413_8 + t * (-1.453_152 + t * 1.061_405_4))));
    let erf = 1.0 - poly * density;
    (0.5 + 0.5 * erf.copysign(x), FRAC_1_SQRT_2PI * density)
}

/// `gelu(x)` of every element, in parallel.
fn forward_host(x: &[f32]) -> Vec<f32> {
    let mut out = vec![0.0; x.len()];
    out.par_chunks_mut(CHUNK).zip(x.par_chunks(CHUNK)).for_each(|(o, x)| {
        for (o, &x) in o.iter_mut().zip(x) {
            *o = x * normal_cdf_pdf(x).0;
        }
    });
    out
}

/// `grad · gelu'(x)` of every element, in parallel.
fn backward_host(x: &[f32], grad: &[f32]) -> Vec<f32> {
    let mut out = vec![0.0; x.len()];
    out.par_chunks_mut(CHUNK).zip(x.par_chunks(CHUNK).zip(grad.par_chunks(CHUNK))).for_each(
        |(o, (x, g))| {
            for ((o, &x), &g) in o.iter_mut().zip(x).zip(g) {
                let (cdf, pdf) = normal_cdf_pdf(x);
                *o = g * (cdf + x * pdf);
            }
        },
    );
    out
}

/// The GELU of `x`, element-wise.
pub fn gelu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let ours = match (x.dtype(), x.device().gradient_checkpointing_strategy()) {
        (DType::F32, None) => untracked(&x),
        (DType::F32, Some(GradientCheckpointingStrategy::Disabled)) => {
            tracked::<NoCheckpointing, D>(&x)
        }
        (DType::F32, Some(GradientCheckpointingStrategy::Balanced)) => {
            tracked::<BalancedCheckpointing, D>(&x)
        }
        _ => None,
    };
    ours.unwrap_or_else(|| burn::tensor::activation::gelu(x))
}

/// The forward on a plain Flex device; `None` on any other.
fn untracked<const D: usize>(x: &Tensor<D>) -> Option<Tensor<D>> {
    x.clone().try_into_primitive::<Flex>().ok()?;
    let host = x.to_data().try_into_vec::<f32>().ok()?;
    Some(Tensor::from_data(TensorData::new(forward_host(&host), x.shape()), &x.device()))
}

/// The op in the graph of `Autodiff<Flex, C>`; `None` when `x` lives elsewhere.
fn tracked<C: CheckpointStrategy, const D: usize>(x: &Tensor<D>) -> Option<Tensor<D>>
where
    DispatchTensor: DispatchKindConversion<Autodiff<Flex, C>>,
{
    let input = x.clone().try_into_primitive::<Autodiff<Flex, C>>().ok()?;
    let host = Arc::new(x.to_data().try_into_vec::<f32>().ok()?);
    let out =
        Flex::float_from_data(TensorData::new(forward_host(&host), x.shape()), &input.device());
    let result = match GeluBackward::<D>.prepare::<C>([input.node()]).compute_bound().stateful() {
        OpsKind::Tracked(prep) => prep.finish(host, out),
        OpsKind::UnTracked(prep) => prep.finish(out),
    };
    Some(Tensor::from_primitive::<Autodiff<Flex, C>>(result))
}

#[derive(Debug)]
struct GeluBackward<const D: usize>;

impl<const D: usize> Backward<Flex, 1> for GeluBackward<D> {
    /// The input, on the host.
    type State = Arc<Vec<f32>>;

    fn backward(
        self,
        ops: Ops<Self::State, 1>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let x = ops.state;
        unary::<Flex, _>(ops.parents, ops.node, grads, |grad| {
            let device = grad.device();
            let grad = Tensor::<D>::from_primitive::<Flex>(grad);
            let shape = grad.shape();
            let grad = grad
                .into_data()
                .try_into_vec::<f32>()
                .expect("the gradient of a float32 GELU is float32");
            Flex::float_from_data(TensorData::new(backward_host(&x, &grad), shape), &device)
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs() -> Vec<f32> {
        (-20_000..=20_000).map(|i| i as f32 / 2000.0).collect()
    }

    /// Within 4·10⁻⁷ · max(1, |x|) (a few float32 steps) of burn's GELU (libm's erf) from −10
    /// to 10, on a plain device and an autodiff one, over three parallel chunks.
    #[test]
    fn gelu_matches_burns_exact_gelu() {
        let xs = inputs();
        for device in [Device::flex(), Device::flex().autodiff()] {
            let x = Tensor::<1>::from_floats(xs.as_slice(), &device).reshape([1, 40_001]);
            let ours = gelu(x.clone()).into_data().try_into_vec::<f32>().unwrap();
            let theirs =
                burn::tensor::activation::gelu(x).into_data().try_into_vec::<f32>().unwrap();
            for ((a, b), x) in ours.iter().zip(&theirs).zip(&xs) {
                assert!((a - b).abs() <= 4e-7 * x.abs().max(1.0), "gelu({x}) = {a}, burn says {b}");
            }
        }
    }

    /// The backward against central finite differences of the forward (step 10⁻³) and
    /// against burn's autodiff of its GELU, each input weighted differently.
    #[test]
    fn gelu_gradient_matches_finite_differences_and_burn() {
        let xs = inputs();
        let device = Device::flex().autodiff();
        let weights: Vec<f32> = (0..xs.len()).map(|i| 1.0 + (i % 7) as f32 * 0.25).collect();
        let w = Tensor::<1>::from_floats(weights.as_slice(), &device);
        let grad_of = |f: &dyn Fn(Tensor<1>) -> Tensor<1>| {
            let x = Tensor::<1>::from_floats(xs.as_slice(), &device).require_grad();
            let grads = (f(x.clone()) * w.clone()).sum().backward();
            x.grad(&grads).expect("a gradient").into_data().try_into_vec::<f32>().unwrap()
        };
        let ours = grad_of(&|x| gelu(x));
        let theirs = grad_of(&|x| burn::tensor::activation::gelu(x));
        let h = 1e-3f32;
        for (i, &x) in xs.iter().enumerate() {
            let f = |x: f32| x * normal_cdf_pdf(x).0;
            let numeric = weights[i] * (f(x + h) - f(x - h)) / (2.0 * h);
            assert!(
                (ours[i] - numeric).abs() < 2e-3,
                "d gelu({x}): {} against finite differences {numeric}",
                ours[i]
            );
            assert!(
                (ours[i] - theirs[i]).abs() < 1e-6,
                "d gelu({x}): {} against burn's {}",
                ours[i],
                theirs[i]
            );
        }
    }
}
