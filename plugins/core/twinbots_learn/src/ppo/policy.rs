//! The actor-critic: separate policy and value MLPs (SB3's MlpPolicy: two hidden layers of 64,
//! tanh), a categorical head for discrete actions and a diagonal Gaussian for boxes. On camera
//! images both MLPs read the features of one shared NatureCNN (SB3's CnnPolicy, whose
//! on-policy features extractor is shared), or each its own (`share_features_extractor =
//! false`, SB3's policy keyword of that name): the value's regression then cannot reshape the
//! features the policy reads.

use candle_core::{D, DType, Device, Result, Tensor, Var};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use twinbots_api::spaces::Space;

use crate::nn::fused_mlp::HALF_LOG_2PI;
use crate::nn::{Dense, Encoder, PolicyKind};

/// Hidden layers with tanh, then a linear output.
pub struct Mlp {
    pub layers: Vec<Dense>,
}

impl Mlp {
    fn new(sizes: &[usize], out_gain: f64, rng: &mut ChaCha8Rng, dev: &Device) -> Result<Self> {
        let last = sizes.len() - 2;
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, w)| Dense::new(w[0], w[1], if i == last { out_gain } else { 1.0 }, rng, dev))
            .collect::<Result<_>>()?;
        Ok(Self { layers })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            if i + 1 < self.layers.len() {
                h = crate::nn::tanh(&h)?;
            }
        }
        Ok(h)
    }
}

/// The action distribution's family.
pub enum Head {
    Categorical { n: usize },
    Gaussian { dim: usize, log_std: Var },
}

pub struct ActorCritic {
    pub encoder: Encoder,
    /// The value's own encoder where features are not shared (a CNN only); `None`: the value
    /// reads `encoder`'s features too.
    pub value_encoder: Option<Encoder>,
    pub pi: Mlp,
    pub vf: Mlp,
    pub head: Head,
}

/// Log-probabilities and entropies of a batch of actions under the current policy.
pub struct Evaluation {
    pub log_prob: Tensor,
    pub entropy: Tensor,
    pub value: Tensor,
}

impl ActorCritic {
    /// Networks for observations of `observation_space` read through the encoder `policy`
    /// asks for (`features_dim` CNN features, one CNN for both MLPs or, not `shared`, one
    /// each); a box's Gaussian starts with log std `log_std_init`.
    pub fn new(
        observation_space: &Space,
        action_space: &Space,
        (policy, features_dim, shared): (PolicyKind, usize, bool),
        hidden: &[usize],
        log_std_init: f32,
        seed: u64,
    ) -> anyhow::Result<Self> {
        let dev = Device::Cpu;
        let mut rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed);
        // The CNN draws its weights from a stream of its own, so an MLP policy keeps its old ones.
        let mut encoder_rng = <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed ^ twinbots_api::seeds::PPO_ENCODER);
        let encoder = Encoder::new(policy, observation_space, features_dim, super::NAME, &mut encoder_rng, &dev)?;
        let value_encoder = match &encoder {
            Encoder::Cnn { .. } | Encoder::Keypoints { .. } if !shared => {
                let mut rng =
                    <ChaCha8Rng as rand::SeedableRng>::seed_from_u64(seed ^ twinbots_api::seeds::PPO_VALUE_ENCODER);
                Some(Encoder::new(policy, observation_space, features_dim, super::NAME, &mut rng, &dev)?)
            }
            _ => None,
        };
        let obs_dim = encoder.dim();
        let (out, head) = match action_space {
            Space::Discrete { n } => (*n, Head::Categorical { n: *n }),
            Space::Box { low, .. } => (
                low.len(),
                Head::Gaussian {
                    dim: low.len(),
                    log_std: Var::from_tensor(&Tensor::full(log_std_init, low.len(), &dev)?)?,
                },
            ),
            other => anyhow::bail!("{other} actions are not supported by PPO yet"),
        };
        let sizes = |o: usize| [&[obs_dim][..], hidden, &[o]].concat();
        // SB3's gains: 0.01 for the policy output (a near-uniform start), 1 for the value.
        let pi = Mlp::new(&sizes(out), 0.01, &mut rng, &dev)?;
        let vf = Mlp::new(&sizes(1), 1.0, &mut rng, &dev)?;
        Ok(Self { encoder, value_encoder, pi, vf, head })
    }

    /// A copy whose variables share nothing with these (candle's `Var`s are shared handles:
    /// cloning one would train both copies).
    pub fn deep_copy(&self) -> Result<Self> {
        let copy = |v: &Var| Var::from_tensor(&v.as_tensor().copy()?);
        let mlp = |m: &Mlp| -> Result<Mlp> {
            Ok(Mlp { layers: m.layers.iter().map(Dense::deep_copy).collect::<Result<_>>()? })
        };
        let head = match &self.head {
            Head::Categorical { n } => Head::Categorical { n: *n },
            Head::Gaussian { dim, log_std } => Head::Gaussian { dim: *dim, log_std: copy(log_std)? },
        };
        let value_encoder = self.value_encoder.as_ref().map(Encoder::deep_copy).transpose()?;
        Ok(Self { encoder: self.encoder.deep_copy()?, value_encoder, pi: mlp(&self.pi)?, vf: mlp(&self.vf)?, head })
    }

    /// Every trainable variable, in a fixed order (the save format's order too).
    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let mut out = self.encoder.named_vars();
        if let Some(e) = &self.value_encoder {
            out.extend(e.named_vars().into_iter().map(|(n, v)| (format!("vf_{n}"), v)));
        }
        for (net, mlp) in [("pi", &self.pi), ("vf", &self.vf)] {
            for (i, l) in mlp.layers.iter().enumerate() {
                out.push((format!("{net}.{i}.weight"), l.weight.clone()));
                out.push((format!("{net}.{i}.bias"), l.bias.clone()));
            }
        }
        if let Head::Gaussian { log_std, .. } = &self.head {
            out.push(("log_std".into(), log_std.clone()));
        }
        out
    }

    /// Sets every variable from `tensors` by its name in [`Self::named_vars`]
    /// ([`crate::model_io::set_vars`]: each checked); extra tensors are ignored.
    pub fn set_weights(&self, tensors: &std::collections::HashMap<String, Tensor>) -> anyhow::Result<()> {
        crate::model_io::set_vars(&self.named_vars(), tensors)
    }

    pub fn value(&self, obs: &Tensor) -> Result<Tensor> {
        let encoder = self.value_encoder.as_ref().unwrap_or(&self.encoder);
        self.vf.forward(&encoder.forward(obs)?)?.squeeze(D::Minus1)
    }

    /// V from the encoders' features ([`Self::features`]): the value's own, or else the policy's.
    fn value_from(&self, features: &Tensor, value_features: Option<&Tensor>) -> Result<Tensor> {
        self.vf.forward(value_features.unwrap_or(features))?.squeeze(D::Minus1)
    }

    /// Samples (or, deterministic, takes the mode of) one action per row of `obs`.
    /// Returns flat actions, their log-probabilities, and the values.
    pub fn act(
        &self,
        obs: &Tensor,
        deterministic: bool,
        rng: &mut ChaCha8Rng,
    ) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
        let (features, value_features) = self.features(obs)?;
        self.act_from(&features, value_features.as_ref(), deterministic, rng)
    }

    /// [`Self::act`] from the encoders' features ([`Self::features`]).
    pub fn act_from(
        &self,
        features: &Tensor,
        value_features: Option<&Tensor>,
        deterministic: bool,
        rng: &mut ChaCha8Rng,
    ) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
        let out = self.pi.forward(features)?.flatten_all()?.to_vec1::<f32>()?;
        let value = self.value_from(features, value_features)?.to_vec1::<f32>()?;
        let (actions, log_probs) = sample(&self.head, &out, &self.log_std_values()?, deterministic, rng);
        Ok((actions, log_probs, value))
    }

    /// The Gaussian's log σ per action dimension; none for a categorical head.
    pub(super) fn log_std_values(&self) -> Result<Vec<f32>> {
        match &self.head {
            Head::Gaussian { log_std, .. } => log_std.as_tensor().to_vec1::<f32>(),
            Head::Categorical { .. } => Ok(Vec::new()),
        }
    }

    /// Log-probabilities, entropies and values for stored (obs, action) pairs, with gradients.
    pub fn evaluate(&self, obs: &Tensor, actions: &Tensor) -> Result<Evaluation> {
        let (features, value_features) = self.features(obs)?;
        self.evaluate_features(&features, value_features.as_ref(), actions)
    }

    /// The policy's features of `obs`, and the value's where it has an encoder of its own.
    pub fn features(&self, obs: &Tensor) -> Result<(Tensor, Option<Tensor>)> {
        Ok((self.encoder.forward(obs)?, self.value_encoder.as_ref().map(|e| e.forward(obs)).transpose()?))
    }

    /// [`Self::evaluate`] from the encoders' features (the value's own, or else the policy's):
    /// no gradient reaches the encoders.
    pub fn evaluate_features(
        &self,
        features: &Tensor,
        value_features: Option<&Tensor>,
        actions: &Tensor,
    ) -> Result<Evaluation> {
        let out = self.pi.forward(features)?;
        let value = self.value_from(features, value_features)?;
        let (log_prob, entropy) = match &self.head {
            Head::Categorical { .. } => {
                let log_p = candle_nn::ops::log_softmax(&out, D::Minus1)?;
                let idx = actions.to_dtype(DType::U32)?.unsqueeze(1)?;
                let log_prob = log_p.gather(&idx, 1)?.squeeze(1)?;
                let entropy = (log_p.exp()? * &log_p)?.sum(1)?.neg()?;
                (log_prob, entropy)
            }
            Head::Gaussian { log_std, .. } => {
                let log_std = log_std.as_tensor();
                let z = actions.broadcast_sub(&out)?.broadcast_div(&log_std.exp()?)?;
                let half_log_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
                let log_prob = ((z.sqr()? * -0.5)?.broadcast_sub(log_std)? - half_log_2pi)?.sum(1)?;
                let entropy = (log_std + (0.5 + half_log_2pi))?.sum_all()?;
                let entropy = entropy.broadcast_as(log_prob.shape())?.contiguous()?;
                (log_prob, entropy)
            }
        };
        Ok(Evaluation { log_prob, entropy, value })
    }
}

/// ln Σ e^l of a row of logits, as max + ln Σ e^{l − max}: log softmax is l − this.
pub(super) fn log_sum_exp(logits: &[f32]) -> f32 {
    let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    max + logits.iter().map(|l| (l - max).exp()).sum::<f32>().ln()
}

/// One action per row of the policy network's output `out` (logits, or the Gaussian's means
/// with `log_std`, empty for a categorical head), sampled or, deterministic, the mode; and its
/// log-probability.
pub(super) fn sample(
    head: &Head,
    out: &[f32],
    log_std: &[f32],
    deterministic: bool,
    rng: &mut ChaCha8Rng,
) -> (Vec<f32>, Vec<f32>) {
    match head {
        Head::Gaussian { dim, .. } => {
            let mut actions = Vec::with_capacity(out.len());
            let mut log_probs = Vec::with_capacity(out.len() / dim);
            for row in out.chunks_exact(*dim) {
                let mut lp = 0.0;
                for k in 0..*dim {
                    let z: f32 = if deterministic { 0.0 } else { StandardNormal.sample(rng) };
                    actions.push(row[k] + z * log_std[k].exp());
                    lp += -0.5 * z * z - log_std[k] - HALF_LOG_2PI;
                }
                log_probs.push(lp);
            }
            (actions, log_probs)
        }
        Head::Categorical { n } => {
            let n = *n;
            let mut actions = Vec::with_capacity(out.len() / n);
            let mut log_probs = Vec::with_capacity(out.len() / n);
            for logits in out.chunks_exact(n) {
                let log_sum = log_sum_exp(logits);
                let log_p = |i: usize| logits[i] - log_sum;
                let a = if deterministic {
                    crate::policy_net::arg_max(logits)
                } else {
                    let u: f32 = rng.random();
                    let mut acc = 0.0;
                    (0..n)
                        .find(|&i| {
                            acc += log_p(i).exp();
                            u < acc
                        })
                        .unwrap_or(n - 1)
                };
                actions.push(a as f32);
                log_probs.push(log_p(a));
            }
            (actions, log_probs)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unshared_value_cnn_is_the_only_cnn_the_value_loss_reaches() {
        let space = Space::Image { height: 40, width: 40, channels: 3 };
        let actions = Space::uniform_box(2, -1.0, 1.0);
        let obs = Tensor::rand(0f32, 255.0, (4, space.dim()), &Device::Cpu).unwrap();
        let value_grads = |shared: bool| {
            let net = ActorCritic::new(&space, &actions, (PolicyKind::Cnn, 16, shared), &[8], 0.0, 3).unwrap();
            let grads = net.value(&obs).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap();
            let reached = |name: &str| net.named_vars().into_iter().any(|(n, v)| n == name && grads.get(&v).is_some());
            (reached("features.0.weight"), reached("vf_features.0.weight"), net.named_vars().len())
        };
        // The shared CNN's 8 variables, 2 × 2 MLP layers', log σ; unshared: 8 more.
        assert_eq!(value_grads(true), (true, false, 8 + 8 + 1));
        assert_eq!(value_grads(false), (false, true, 16 + 8 + 1));
    }
}
