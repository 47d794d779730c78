//! Adam (Kingma and Ba 2015) as PyTorch runs it, with the global gradient-norm clipping of
//! `clip_grad_norm_` in the same pass, over plain slices.
//!
//! candle-nn's `AdamW` does a dozen tensor ops per variable and step, and clipping another
//! three: for the twelve small tensors of an actor-critic that was a quarter of a PPO update.
//! Here each variable costs one read of its gradient, one of its value and one write. The
//! moments are ours, not hidden, so a checkpoint can keep them.

use candle_core::backprop::GradStore;
use candle_core::{Result, Tensor, Var};

/// Adam's hyperparameters; the defaults are SB3's (PyTorch's, with eps 1e-5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    pub learning_rate: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { learning_rate: 3e-4, beta1: 0.9, beta2: 0.999, eps: 1e-5 }
    }
}

/// What one call of [`Adam::step`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GradientStep {
    /// The global L2 norm of the gradients, before clipping.
    pub grad_norm: f32,
    /// False when the norm was not finite: the weights and moments were left as they were.
    pub applied: bool,
}

pub struct Adam {
    vars: Vec<Var>,
    /// First and second moment estimates per variable, flat in the variable's element order.
    first: Vec<Vec<f32>>,
    second: Vec<Vec<f32>>,
    steps: u64,
    pub config: AdamConfig,
}

impl Adam {
    pub fn new(vars: Vec<Var>, config: AdamConfig) -> Self {
        let zeros = |v: &Var| vec![0.0; v.elem_count()];
        Self {
            first: vars.iter().map(zeros).collect(),
            second: vars.iter().map(zeros).collect(),
            vars,
            steps: 0,
            config,
        }
    }

    /// The same optimiser state (moments, step count, settings) for a copy of its variables,
    /// e.g. a snapshot of the network, so both continue alike.
    pub fn for_copies(&self, vars: Vec<Var>) -> Result<Self> {
        let same_shapes =
            vars.len() == self.vars.len() && vars.iter().zip(&self.vars).all(|(a, b)| a.shape() == b.shape());
        if !same_shapes {
            candle_core::bail!("Adam::for_copies: the variables differ in number or shape from the optimiser's");
        }
        Ok(Self {
            vars,
            first: self.first.clone(),
            second: self.second.clone(),
            steps: self.steps,
            config: self.config,
        })
    }

    /// The moments (first, second; per variable, flat) and the number of steps taken: what a
    /// checkpoint keeps so a resumed run steps as the uninterrupted one.
    pub fn moments(&self) -> (&[Vec<f32>], &[Vec<f32>], u64) {
        (&self.first, &self.second, self.steps)
    }

    /// Puts back moments taken by [`Adam::moments`]; an error if they do not fit the variables.
    pub fn restore_moments(&mut self, first: Vec<Vec<f32>>, second: Vec<Vec<f32>>, steps: u64) -> Result<()> {
        let fits = |m: &[Vec<f32>]| {
            m.len() == self.vars.len() && m.iter().zip(&self.vars).all(|(m, v)| m.len() == v.elem_count())
        };
        if !fits(&first) || !fits(&second) {
            candle_core::bail!("the optimiser's saved moments do not fit the network's variables");
        }
        if first.iter().chain(&second).flatten().any(|x| !x.is_finite()) {
            candle_core::bail!("the optimiser's saved moments are not finite");
        }
        (self.first, self.second, self.steps) = (first, second, steps);
        Ok(())
    }

    pub fn learning_rate(&self) -> f64 {
        self.config.learning_rate
    }

    pub fn set_learning_rate(&mut self, learning_rate: f64) {
        self.config.learning_rate = learning_rate;
    }

    /// One step along `grads`, scaled first so their global norm is at most `max_grad_norm`
    /// (PyTorch's clip coefficient max / (norm + 1e-6), capped at 1). A variable without a
    /// gradient is left alone, as PyTorch does. Non-finite gradients change nothing.
    pub fn step(&mut self, grads: &GradStore, max_grad_norm: Option<f32>) -> Result<GradientStep> {
        self.step_flat(flat_gradients(&self.vars, grads)?, max_grad_norm)
    }

    /// [`Adam::step`] along `gradients`, flat, one per variable in the optimiser's order
    /// (none: the variable is left alone).
    pub fn step_flat(&mut self, gradients: Vec<Option<Vec<f32>>>, max_grad_norm: Option<f32>) -> Result<GradientStep> {
        if gradients.len() != self.vars.len()
            || gradients.iter().zip(&self.vars).any(|(g, v)| g.as_ref().is_some_and(|g| g.len() != v.elem_count()))
        {
            candle_core::bail!("Adam::step_flat: the gradients do not fit the optimiser's variables");
        }
        let squared: f64 = gradients.iter().flatten().flatten().map(|&g| (g as f64) * (g as f64)).sum();
        let grad_norm = squared.sqrt() as f32;
        if !grad_norm.is_finite() {
            return Ok(GradientStep { grad_norm, applied: false });
        }
        let clip = max_grad_norm.map_or(1.0, |max| (max / (grad_norm + 1e-6)).min(1.0));

        self.steps += 1;
        let AdamConfig { learning_rate, beta1, beta2, eps } = self.config;
        let t = self.steps as i32;
        // θ ← θ − lr m̂ / (√v̂ + ε), with m̂ = m / (1 − β₁ᵗ) and v̂ = v / (1 − β₂ᵗ)
        let step_size = (learning_rate / (1.0 - beta1.powi(t))) as f32;
        let second_correction = (1.0 - beta2.powi(t)).sqrt() as f32;
        let (b1, b2, eps) = (beta1 as f32, beta2 as f32, eps as f32);
        for (i, gradient) in gradients.into_iter().enumerate() {
            let Some(gradient) = gradient else { continue };
            let var = &self.vars[i];
            let mut value = var.as_tensor().flatten_all()?.to_vec1::<f32>()?;
            let (m, v) = (&mut self.first[i], &mut self.second[i]);
            for (((p, m), v), g) in value.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(&gradient) {
                let g = g * clip;
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                *p -= step_size * *m / (v.sqrt() / second_correction + eps);
            }
            var.set(&Tensor::from_vec(value, var.shape(), var.device())?)?;
        }
        Ok(GradientStep { grad_norm, applied: true })
    }
}

/// The sum of several losses' gradients (flat, one per variable, as [`flat_gradients`] gives
/// them), added in order: a minibatch's gradient from its parts'.
pub fn sum_gradients<'a>(parts: impl IntoIterator<Item = &'a [Option<Vec<f32>>]>) -> Vec<Option<Vec<f32>>> {
    let mut sum: Vec<Option<Vec<f32>>> = Vec::new();
    for part in parts {
        sum.resize(sum.len().max(part.len()), None);
        for (total, g) in sum.iter_mut().zip(part) {
            match (total.as_mut(), g) {
                (Some(total), Some(g)) => total.iter_mut().zip(g).for_each(|(t, g)| *t += g),
                (None, Some(g)) => *total = Some(g.clone()),
                (_, None) => {}
            }
        }
    }
    sum
}

/// Each of `vars`' gradient in `grads`, flat (none where the loss did not reach it).
pub fn flat_gradients(vars: &[Var], grads: &GradStore) -> Result<Vec<Option<Vec<f32>>>> {
    vars.iter().map(|v| grads.get(v.as_tensor()).map(|g| g.flatten_all()?.to_vec1::<f32>()).transpose()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use candle_nn::{AdamW, Optimizer, ParamsAdamW};

    fn quadratic_loss(vars: &[Var]) -> Tensor {
        let targets = [3.0f64, -1.5];
        let terms: Vec<Tensor> = vars
            .iter()
            .zip(targets)
            .map(|(v, t)| (v.as_tensor() - t).unwrap().sqr().unwrap().sum_all().unwrap())
            .collect();
        (&terms[0] + (&terms[1] * 10.0).unwrap()).unwrap()
    }

    fn vars() -> Vec<Var> {
        let dev = Device::Cpu;
        vec![
            Var::from_tensor(&Tensor::new(&[[0.5f32, -0.25], [1.0, 2.0]], &dev).unwrap()).unwrap(),
            Var::from_tensor(&Tensor::new(&[0.1f32, 0.2, 0.3], &dev).unwrap()).unwrap(),
        ]
    }

    #[test]
    fn steps_like_candles_adam_without_clipping() {
        let (ours, theirs) = (vars(), vars());
        let config = AdamConfig { learning_rate: 0.05, ..AdamConfig::default() };
        let mut adam = Adam::new(ours.clone(), config);
        let params = ParamsAdamW { lr: 0.05, beta1: 0.9, beta2: 0.999, eps: 1e-5, weight_decay: 0.0 };
        let mut reference = AdamW::new(theirs.clone(), params).unwrap();
        for _ in 0..50 {
            let step = adam.step(&quadratic_loss(&ours).backward().unwrap(), None).unwrap();
            assert!(step.applied && step.grad_norm > 0.0);
            reference.step(&quadratic_loss(&theirs).backward().unwrap()).unwrap();
        }
        for (a, b) in ours.iter().zip(&theirs) {
            let diff =
                (a.as_tensor() - b.as_tensor()).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
            // f32 rounding in a different order; a missing bias correction would differ by ~lr.
            assert!(diff < 1e-4, "{diff}");
        }
        let loss = quadratic_loss(&ours).to_scalar::<f32>().unwrap();
        assert!(loss < quadratic_loss(&vars()).to_scalar::<f32>().unwrap() / 2.0, "Adam did not descend: {loss}");
    }

    #[test]
    fn clipping_bounds_the_first_step_and_non_finite_gradients_change_nothing() {
        // Adam's first step is ±lr per element whatever the scale, so clipping shows in the
        // moments: a clipped gradient of norm ≤ max leaves m = (1 − β₁) g with |g| ≤ max.
        let ours = vars();
        let mut adam = Adam::new(ours.clone(), AdamConfig::default());
        let step = adam.step(&quadratic_loss(&ours).backward().unwrap(), Some(0.5)).unwrap();
        assert!(step.grad_norm > 0.5);
        let m_norm: f32 = adam.first.iter().flatten().map(|m| m * m).sum::<f32>().sqrt();
        assert!((m_norm - 0.1 * 0.5).abs() < 1e-6, "first moment norm {m_norm}");

        let before: Vec<Vec<f32>> = ours.iter().map(|v| v.flatten_all().unwrap().to_vec1().unwrap()).collect();
        let poisoned = (quadratic_loss(&ours) * f64::NAN).unwrap();
        let step = adam.step(&poisoned.backward().unwrap(), Some(0.5)).unwrap();
        assert!(!step.applied && step.grad_norm.is_nan());
        let after: Vec<Vec<f32>> = ours.iter().map(|v| v.flatten_all().unwrap().to_vec1().unwrap()).collect();
        assert_eq!(before, after);
        assert_eq!(adam.steps, 1);
    }
}
