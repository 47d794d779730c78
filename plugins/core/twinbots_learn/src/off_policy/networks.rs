//! The off-policy learners' critics (SAC's and TD3's, as SB3's): twin Q networks over
//! (observation, action), each with its target copy updated by Polyak averaging, and the ReLU
//! MLPs they and TD3's actor are made of. On camera images the two Q heads share the critics'
//! NatureCNN, and the target critics have their own copy.

use candle_core::{Device, Result, Tensor, Var};
use rand_chacha::ChaCha8Rng;

use crate::nn::{Dense, Encoder};

/// Dense layers with ReLU after every one (`relu_last`) or all but the last.
pub struct ReluMlp {
    pub layers: Vec<Dense>,
    pub(crate) relu_last: bool,
}

impl ReluMlp {
    pub(crate) fn new(sizes: &[usize], relu_last: bool, rng: &mut ChaCha8Rng, dev: &Device) -> Result<Self> {
        let layers = sizes.windows(2).map(|w| Dense::new(w[0], w[1], 1.0, rng, dev)).collect::<Result<_>>()?;
        Ok(Self { layers, relu_last })
    }

    pub(crate) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            if self.relu_last || i + 1 < self.layers.len() {
                h = crate::nn::relu(&h)?;
            }
        }
        Ok(h)
    }

    pub(crate) fn named_vars(&self, prefix: &str, out: &mut Vec<(String, Var)>) {
        for (i, l) in self.layers.iter().enumerate() {
            out.push((format!("{prefix}.{i}.weight"), l.weight.clone()));
            out.push((format!("{prefix}.{i}.bias"), l.bias.clone()));
        }
    }

    /// Its variables, named `<prefix>.<i>.weight` and `<prefix>.<i>.bias`.
    pub(crate) fn vars(&self, prefix: &str) -> Vec<(String, Var)> {
        let mut out = Vec::new();
        self.named_vars(prefix, &mut out);
        out
    }
}

/// Q₁(s, a) and Q₂(s, a): two independent MLPs (clipped double Q).
pub struct TwinCritic {
    pub encoder: Encoder,
    pub(crate) q1: ReluMlp,
    pub(crate) q2: ReluMlp,
}

impl TwinCritic {
    /// Twin critics reading `encoder`'s features.
    pub fn new(encoder: Encoder, act_dim: usize, hidden: &[usize], rng: &mut ChaCha8Rng) -> Result<Self> {
        let dev = Device::Cpu;
        let sizes = [&[encoder.dim() + act_dim][..], hidden, &[1]].concat();
        Ok(Self { q1: ReluMlp::new(&sizes, false, rng, &dev)?, q2: ReluMlp::new(&sizes, false, rng, &dev)?, encoder })
    }

    /// (Q₁, Q₂), one value per row.
    pub fn q(&self, obs: &Tensor, actions: &Tensor) -> Result<(Tensor, Tensor)> {
        self.q_of(&self.encoder.forward(obs)?, actions)
    }

    /// (Q₁, Q₂) from the encoder's features of the observations (computed once, used twice).
    pub fn q_of(&self, features: &Tensor, actions: &Tensor) -> Result<(Tensor, Tensor)> {
        let x = Tensor::cat(&[features, actions], 1)?;
        Ok((self.q1.forward(&x)?.squeeze(1)?, self.q2.forward(&x)?.squeeze(1)?))
    }

    /// min(Q₁, Q₂).
    pub fn min_q(&self, obs: &Tensor, actions: &Tensor) -> Result<Tensor> {
        self.min_q_of(&self.encoder.forward(obs)?, actions)
    }

    /// min(Q₁, Q₂) from the encoder's features.
    pub fn min_q_of(&self, features: &Tensor, actions: &Tensor) -> Result<Tensor> {
        let (q1, q2) = self.q_of(features, actions)?;
        q1.minimum(&q2)
    }

    pub fn named_vars(&self, prefix: &str) -> Vec<(String, Var)> {
        let mut out: Vec<(String, Var)> =
            self.encoder.named_vars().into_iter().map(|(n, v)| (format!("{prefix}.{n}"), v)).collect();
        self.q1.named_vars(&format!("{prefix}.q1"), &mut out);
        self.q2.named_vars(&format!("{prefix}.q2"), &mut out);
        out
    }

    /// A copy sharing no variables (the target network starts as the critic).
    pub fn deep_copy(&self) -> Result<Self> {
        let copy = |m: &ReluMlp| -> Result<ReluMlp> {
            Ok(ReluMlp {
                layers: m.layers.iter().map(Dense::deep_copy).collect::<Result<_>>()?,
                relu_last: m.relu_last,
            })
        };
        Ok(Self { encoder: self.encoder.deep_copy()?, q1: copy(&self.q1)?, q2: copy(&self.q2)? })
    }
}

/// θ' ← τ θ + (1 − τ) θ' for each (target, source) pair, over plain slices.
pub fn polyak_update(target: &[(String, Var)], source: &[(String, Var)], tau: f32) -> Result<()> {
    for ((_, t), (_, s)) in target.iter().zip(source) {
        let mut tv = t.as_tensor().flatten_all()?.to_vec1::<f32>()?;
        let sv = s.as_tensor().flatten_all()?.to_vec1::<f32>()?;
        for (a, b) in tv.iter_mut().zip(&sv) {
            *a += tau * (b - *a);
        }
        t.set(&Tensor::from_vec(tv, t.shape(), t.device())?)?;
    }
    Ok(())
}
