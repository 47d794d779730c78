//! The dense layer every network is made of.

use candle_core::{Device, Result, Tensor, Var};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// A dense layer `y = x W^T + b`.
pub struct Dense {
    pub weight: Var,
    pub bias: Var,
}

impl Dense {
    /// PyTorch's default init, U(±1/√fan_in), scaled by `gain`, from our own seeded stream so
    /// the seed fixes the network.
    pub(crate) fn new(inputs: usize, outputs: usize, gain: f64, rng: &mut ChaCha8Rng, dev: &Device) -> Result<Self> {
        let bound = (1.0 / inputs as f64).sqrt();
        let mut uniform =
            |n: usize| -> Vec<f32> { (0..n).map(|_| (rng.random_range(-bound..bound) * gain) as f32).collect() };
        Ok(Self {
            weight: Var::from_tensor(&Tensor::from_vec(uniform(inputs * outputs), (outputs, inputs), dev)?)?,
            bias: Var::from_tensor(&Tensor::from_vec(uniform(outputs), outputs, dev)?)?,
        })
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        // The bias enters as 1 bᵀ, a product, rather than a broadcast add: the gradient of a
        // broadcast sums over the batch dimension, which candle does element by element
        // (14 % of a PPO update), while the product's gradient 1ᵀ G is one gemm call.
        self.add_bias(&x.matmul(&self.weight.as_tensor().t()?)?)
    }

    /// `xWᵀ + 1 bᵀ` from the product `xWᵀ`.
    pub(crate) fn add_bias(&self, product: &Tensor) -> Result<Tensor> {
        let ones = Tensor::ones((product.dim(0)?, 1), product.dtype(), product.device())?;
        product + ones.matmul(&self.bias.as_tensor().unsqueeze(0)?)?
    }
}

impl Dense {
    /// A copy sharing no variable with this one (candle's `Var`s are shared handles).
    pub(crate) fn deep_copy(&self) -> Result<Self> {
        let copy = |v: &Var| Var::from_tensor(&v.as_tensor().copy()?);
        Ok(Self { weight: copy(&self.weight)?, bias: copy(&self.bias)? })
    }

    /// The layer's numbers, named `name` (for export).
    pub fn values(&self, name: &str) -> Result<crate::policy_net::DenseLayer> {
        let (outputs, inputs) = self.weight.as_tensor().dims2()?;
        Ok(crate::policy_net::DenseLayer {
            name: name.to_string(),
            inputs,
            outputs,
            weight: self.weight.as_tensor().flatten_all()?.to_vec1()?,
            bias: self.bias.as_tensor().to_vec1()?,
        })
    }
}

/// The numbers of a stack of layers, named `<prefix>.<i>` (for export).
pub fn layer_values(layers: &[Dense], prefix: &str) -> Result<Vec<crate::policy_net::DenseLayer>> {
    layers.iter().enumerate().map(|(i, l)| l.values(&format!("{prefix}.{i}"))).collect()
}
