//! Gymnasium's CartPole-v1 and Pendulum-v1, from their published equations, in plain Rust:
//! fast, physics-engine-free envs for testing the algorithms.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use twinbots_api::EpisodeSummary;
use twinbots_api::env::{StepResult, VecEnv};
use twinbots_api::spaces::Space;

const GRAVITY: f32 = 9.8;
const MASS_CART: f32 = 1.0;
const MASS_POLE: f32 = 0.1;
const TOTAL_MASS: f32 = MASS_CART + MASS_POLE;
const HALF_LENGTH: f32 = 0.5;
const POLE_MASS_LENGTH: f32 = MASS_POLE * HALF_LENGTH;
const FORCE_MAG: f32 = 10.0;
const TAU: f32 = 0.02;
const THETA_LIMIT: f32 = 12.0 * 2.0 * std::f32::consts::PI / 360.0;
const X_LIMIT: f32 = 2.4;
const MAX_STEPS: u32 = 500;

/// N independent CartPole-v1 envs (Euler integration, +1 per step, truncated at 500 steps).
pub struct ClassicCartPole {
    states: Vec<[f32; 4]>,
    steps: Vec<u32>,
    rng: ChaCha8Rng,
    observation_space: Space,
    action_space: Space,
}

impl ClassicCartPole {
    pub fn new(n: usize) -> Self {
        let high = [X_LIMIT * 2.0, f32::MAX, THETA_LIMIT * 2.0, f32::MAX];
        Self {
            states: vec![[0.0; 4]; n],
            steps: vec![0; n],
            rng: ChaCha8Rng::seed_from_u64(0),
            observation_space: Space::Box { low: high.iter().map(|h| -h).collect(), high: high.to_vec() },
            action_space: Space::Discrete { n: 2 },
        }
    }

    fn reset_one(&mut self, i: usize) {
        self.states[i] = std::array::from_fn(|_| self.rng.random_range(-0.05..0.05));
        self.steps[i] = 0;
    }
}

impl VecEnv for ClassicCartPole {
    fn num_envs(&self) -> usize {
        self.states.len()
    }
    fn observation_space(&self) -> &Space {
        &self.observation_space
    }
    fn action_space(&self) -> &Space {
        &self.action_space
    }

    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        for i in 0..self.states.len() {
            self.reset_one(i);
        }
        Ok(self.states.iter().flatten().copied().collect())
    }

    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        anyhow::ensure!(actions.len() == self.states.len(), "expected {} actions", self.states.len());
        let mut out = StepResult::default();
        for i in 0..self.states.len() {
            let [x, x_dot, theta, theta_dot] = self.states[i];
            let force = if actions[i] >= 0.5 { FORCE_MAG } else { -FORCE_MAG };
            let (sin, cos) = theta.sin_cos();
            let temp = (force + POLE_MASS_LENGTH * theta_dot * theta_dot * sin) / TOTAL_MASS;
            let theta_acc =
                (GRAVITY * sin - cos * temp) / (HALF_LENGTH * (4.0 / 3.0 - MASS_POLE * cos * cos / TOTAL_MASS));
            let x_acc = temp - POLE_MASS_LENGTH * theta_acc * cos / TOTAL_MASS;
            let state = [x + TAU * x_dot, x_dot + TAU * x_acc, theta + TAU * theta_dot, theta_dot + TAU * theta_acc];
            self.states[i] = state;
            self.steps[i] += 1;
            let terminated = state[0].abs() > X_LIMIT || state[2].abs() > THETA_LIMIT;
            let truncated = !terminated && self.steps[i] >= MAX_STEPS;
            out.rewards.push(1.0);
            out.terminated.push(terminated);
            out.truncated.push(truncated);
            if terminated || truncated {
                out.final_obs.push(Some(state.to_vec()));
                out.episodes.push(Some(EpisodeSummary {
                    score: self.steps[i] as f32,
                    length: self.steps[i],
                    ..Default::default()
                }));
                self.reset_one(i);
            } else {
                out.final_obs.push(None);
                out.episodes.push(None);
            }
        }
        out.obs = self.states.iter().flatten().copied().collect();
        Ok(out)
    }
}

/// N independent Pendulum-v1 envs: swing up and hold a 1 m, 1 kg pendulum with torque ≤ 2 N·m.
/// Observation [cos θ, sin θ, θ̇]; reward −(θ² + 0.1 θ̇² + 0.001 u²); truncated at 200 steps.
pub struct ClassicPendulum {
    states: Vec<[f32; 2]>,
    scores: Vec<f32>,
    steps: Vec<u32>,
    rng: ChaCha8Rng,
    observation_space: Space,
    action_space: Space,
}

impl ClassicPendulum {
    const MAX_SPEED: f32 = 8.0;
    const MAX_TORQUE: f32 = 2.0;
    const DT: f32 = 0.05;
    const G: f32 = 10.0;

    pub fn new(n: usize) -> Self {
        Self {
            states: vec![[0.0; 2]; n],
            scores: vec![0.0; n],
            steps: vec![0; n],
            rng: ChaCha8Rng::seed_from_u64(0),
            observation_space: Space::Box { low: vec![-1.0, -1.0, -8.0], high: vec![1.0, 1.0, 8.0] },
            action_space: Space::Box { low: vec![-Self::MAX_TORQUE], high: vec![Self::MAX_TORQUE] },
        }
    }

    fn reset_one(&mut self, i: usize) {
        let pi = std::f32::consts::PI;
        self.states[i] = [self.rng.random_range(-pi..pi), self.rng.random_range(-1.0..1.0)];
        self.steps[i] = 0;
        self.scores[i] = 0.0;
    }

    fn obs(&self) -> Vec<f32> {
        self.states.iter().flat_map(|[th, thdot]| [th.cos(), th.sin(), *thdot]).collect()
    }
}

impl VecEnv for ClassicPendulum {
    fn num_envs(&self) -> usize {
        self.states.len()
    }
    fn observation_space(&self) -> &Space {
        &self.observation_space
    }
    fn action_space(&self) -> &Space {
        &self.action_space
    }

    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        for i in 0..self.states.len() {
            self.reset_one(i);
        }
        Ok(self.obs())
    }

    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        anyhow::ensure!(actions.len() == self.states.len(), "expected {} actions", self.states.len());
        let mut out = StepResult::default();
        for i in 0..self.states.len() {
            let [th, thdot] = self.states[i];
            let u = actions[i].clamp(-Self::MAX_TORQUE, Self::MAX_TORQUE);
            let norm = (th + std::f32::consts::PI).rem_euclid(std::f32::consts::TAU) - std::f32::consts::PI;
            let cost = norm * norm + 0.1 * thdot * thdot + 0.001 * u * u;
            let thdot = (thdot + (3.0 * Self::G / 2.0 * th.sin() + 3.0 * u) * Self::DT)
                .clamp(-Self::MAX_SPEED, Self::MAX_SPEED);
            self.states[i] = [th + thdot * Self::DT, thdot];
            self.steps[i] += 1;
            out.rewards.push(-cost);
            out.terminated.push(false);
            let truncated = self.steps[i] >= 200;
            out.truncated.push(truncated);
            out.final_obs.push(None);
            out.episodes.push(None);
        }
        // Scores are summed here, since an episode's rewards vary.
        for i in 0..self.states.len() {
            self.scores[i] += out.rewards[i];
            if out.truncated[i] {
                let [th, thdot] = self.states[i];
                out.final_obs[i] = Some(vec![th.cos(), th.sin(), thdot]);
                out.episodes[i] =
                    Some(EpisodeSummary { score: self.scores[i], length: self.steps[i], ..Default::default() });
                self.reset_one(i);
            }
        }
        out.obs = self.obs();
        Ok(out)
    }
}
