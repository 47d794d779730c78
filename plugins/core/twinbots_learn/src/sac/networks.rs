//! SAC's actor (SB3's SAC MlpPolicy): a squashed Gaussian head on a ReLU body. Its critics are
//! the off-policy learners' twin Q networks ([`crate::off_policy::networks`]). On camera images
//! (SB3's CnnPolicy) the actor reads its own NatureCNN (SB3's `share_features_extractor=False`
//! for off-policy learners).

use candle_core::{D, Device, Result, Tensor, Var};
use rand_chacha::ChaCha8Rng;

use crate::nn::{Dense, Encoder};
use crate::off_policy::networks::ReluMlp;

/// SB3's bounds on the actor's log standard deviation.
pub(super) const LOG_STD_MIN: f64 = -20.0;
pub(super) const LOG_STD_MAX: f64 = 2.0;

/// π(a|s): a = tanh(u), u ~ N(μ(s), σ(s)), both heads on one ReLU body.
pub struct Actor {
    pub encoder: Encoder,
    pub(super) body: ReluMlp,
    pub(super) mu: Dense,
    pub(super) log_std: Dense,
}

impl Actor {
    /// An actor reading `encoder`'s features.
    pub fn new(encoder: Encoder, act_dim: usize, hidden: &[usize], rng: &mut ChaCha8Rng) -> Result<Self> {
        let dev = Device::Cpu;
        let obs_dim = encoder.dim();
        let sizes = [&[obs_dim][..], hidden].concat();
        let last = *sizes.last().unwrap_or(&obs_dim);
        Ok(Self {
            encoder,
            body: ReluMlp::new(&sizes, true, rng, &dev)?,
            mu: Dense::new(last, act_dim, 1.0, rng, &dev)?,
            log_std: Dense::new(last, act_dim, 1.0, rng, &dev)?,
        })
    }

    fn heads(&self, obs: &Tensor) -> Result<(Tensor, Tensor)> {
        let h = self.body.forward(&self.encoder.forward(obs)?)?;
        Ok((self.mu.forward(&h)?, self.log_std.forward(&h)?.clamp(LOG_STD_MIN, LOG_STD_MAX)?))
    }

    /// The most likely action, tanh(μ(s)), in [-1, 1].
    pub fn mode(&self, obs: &Tensor) -> Result<Tensor> {
        self.heads(obs)?.0.tanh()
    }

    /// Reparameterised samples a = tanh(μ + σ ε) for the standard normal noise `eps`, and
    /// log π(a|s) = Σ [log N(u; μ, σ) − log(1 − tanh²u)], with gradients.
    pub fn sample(&self, obs: &Tensor, eps: &Tensor) -> Result<(Tensor, Tensor)> {
        let (mu, log_std) = self.heads(obs)?;
        let u = (&mu + (log_std.exp()? * eps)?)?;
        let half_log_2pi = 0.5 * (2.0 * std::f64::consts::PI).ln();
        let gaussian = ((eps.sqr()? * -0.5)? - &log_std)? - half_log_2pi;
        // log(1 − tanh²u) = 2 (log 2 − u − softplus(−2u)): exact where tanh saturates.
        let squash = ((softplus(&(&u * -2.0)?)? + &u)?.neg()? + std::f64::consts::LN_2)? * 2.0;
        let log_prob = (gaussian? - squash?)?.sum(D::Minus1)?;
        Ok((u.tanh()?, log_prob))
    }

    /// The layers of the deterministic action tanh(μ(s)): the body, then μ.
    pub fn mode_layers(&self) -> Result<Vec<crate::policy_net::DenseLayer>> {
        let mut layers = crate::nn::layer_values(&self.body.layers, "actor.body")?;
        layers.push(self.mu.values("actor.mu")?);
        Ok(layers)
    }

    pub fn named_vars(&self) -> Vec<(String, Var)> {
        let mut out: Vec<(String, Var)> =
            self.encoder.named_vars().into_iter().map(|(n, v)| (format!("actor.{n}"), v)).collect();
        self.body.named_vars("actor.body", &mut out);
        for (name, l) in [("actor.mu", &self.mu), ("actor.log_std", &self.log_std)] {
            out.push((format!("{name}.weight"), l.weight.clone()));
            out.push((format!("{name}.bias"), l.bias.clone()));
        }
        out
    }
}

/// log(1 + eˣ), stable for large |x|.
fn softplus(x: &Tensor) -> Result<Tensor> {
    x.relu()? + (x.abs()?.neg()?.exp()? + 1.0)?.log()?
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_squashed_log_prob_matches_the_change_of_variables_formula() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let actor = Actor::new(Encoder::Flat { dim: 3 }, 2, &[8], &mut rng).unwrap();
        let obs = Tensor::new(&[[0.3f32, -0.2, 0.9], [1.5, 0.0, -2.0]], &Device::Cpu).unwrap();
        let eps = Tensor::new(&[[0.5f32, -1.0], [2.5, 0.1]], &Device::Cpu).unwrap();
        let (a, log_prob) = actor.sample(&obs, &eps).unwrap();
        let (mu, log_std) = actor.heads(&obs).unwrap();
        let (a, log_prob) = (a.to_vec2::<f32>().unwrap(), log_prob.to_vec1::<f32>().unwrap());
        let (mu, log_std, eps) =
            (mu.to_vec2::<f32>().unwrap(), log_std.to_vec2::<f32>().unwrap(), eps.to_vec2::<f32>().unwrap());
        for r in 0..2 {
            let mut expected = 0.0f64;
            for k in 0..2 {
                let (m, s, e) = (mu[r][k] as f64, (log_std[r][k] as f64).exp(), eps[r][k] as f64);
                let u = m + s * e;
                assert!((u.tanh() - a[r][k] as f64).abs() < 1e-5);
                let normal = -0.5 * e * e - s.ln() - 0.5 * (2.0 * std::f64::consts::PI).ln();
                expected += normal - (1.0 - u.tanh().powi(2)).ln();
            }
            assert!((expected - log_prob[r] as f64).abs() < 1e-3, "row {r}: {expected} vs {}", log_prob[r]);
        }
    }
}
