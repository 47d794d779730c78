//! Reward scaling as SB3's `VecNormalize(norm_reward=True)` does it: each env keeps its
//! discounted return R ← γ R + r (reset when its episode ends), the running variance of those
//! returns is kept, and the reward the learner stores is r / √(var + ε), clipped to ±CLIP.
//! Only the scale changes (no mean is subtracted), so the sign of every reward, and with it
//! which behaviour is best, stays as the task defined it.

use serde::{Deserialize, Serialize};

use crate::normalize::RunningMeanStd;

/// Scaled rewards are clipped to ±this (SB3's `clip_reward`).
pub const CLIP: f32 = 10.0;
const EPSILON: f64 = 1e-8;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RewardScale {
    /// Running statistics of the envs' discounted returns.
    pub return_rms: RunningMeanStd,
    /// Each env's discounted return of its running episode: a checkpoint keeps
    /// them, so a resumed run scales its first rewards as the uninterrupted one does.
    pub returns: Vec<f64>,
}

impl Default for RewardScale {
    fn default() -> Self {
        Self { return_rms: RunningMeanStd::new(1), returns: Vec::new() }
    }
}

impl RewardScale {
    /// One step of every env (`rewards[e]`, and whether its episode ended after it): the
    /// returns and their statistics move (once per step, all envs together, as SB3's do), and
    /// the scaled rewards come back.
    pub fn scale(&mut self, rewards: &[f32], dones: &[bool], gamma: f32) -> Vec<f32> {
        self.returns.resize(rewards.len(), 0.0);
        for (ret, &r) in self.returns.iter_mut().zip(rewards) {
            *ret = *ret * f64::from(gamma) + f64::from(r);
        }
        let returns: Vec<f32> = self.returns.iter().map(|&r| r as f32).collect();
        self.return_rms.update(&returns);
        for (ret, &done) in self.returns.iter_mut().zip(dones) {
            if done {
                *ret = 0.0;
            }
        }
        rewards.iter().map(|&r| self.scaled(r)).collect()
    }

    /// The same for one robot's step (the RobotServer's robots arrive one at a time): `ret`
    /// is that robot's discounted return, which its trajectory keeps.
    pub fn scale_one(&mut self, ret: &mut f64, reward: f32, done: bool, gamma: f32) -> f32 {
        *ret = *ret * f64::from(gamma) + f64::from(reward);
        self.return_rms.update(&[*ret as f32]);
        if done {
            *ret = 0.0;
        }
        self.scaled(reward)
    }

    /// `reward` divided by the returns' standard deviation now, clipped.
    fn scaled(&self, reward: f32) -> f32 {
        ((f64::from(reward) / (self.return_rms.var[0] + EPSILON).sqrt()) as f32).clamp(-CLIP, CLIP)
    }

    /// An error unless the statistics are finite.
    pub fn check_finite(&self) -> anyhow::Result<()> {
        self.return_rms
            .check_finite()
            .map_err(|_| anyhow::anyhow!("the reward statistics are not finite: the model is unusable"))?;
        anyhow::ensure!(
            self.returns.iter().all(|r| r.is_finite()),
            "the running returns are not finite: the model is unusable"
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rewards_are_scaled_by_the_spread_of_the_discounted_return_and_keep_their_sign() {
        let mut scale = RewardScale::default();
        // Two envs: a cost of 5 a step, episodes of 20 steps, ended at different times.
        let mut last = vec![];
        for t in 0..400 {
            let dones = [t % 20 == 19, t % 20 == 9];
            last = scale.scale(&[-5.0, -5.0], &dones, 0.9);
        }
        // Returns run from −5 to −44 (γ 0.9, 20 steps): their standard deviation is over 10,
        // so a step's −5 is stored as −5 / std, under 0.5 in size, and not clipped.
        let std = scale.return_rms.var[0].sqrt();
        assert!((10.0..20.0).contains(&std), "std {std}");
        assert!(last.iter().all(|&r| r < 0.0 && (r + 5.0 / std as f32).abs() < 1e-4), "{last:?}");
        // An episode's end resets that env's return.
        scale.scale(&[-5.0, -5.0], &[true, false], 0.9);
        assert_eq!(scale.returns[0], 0.0);
        assert!(scale.returns[1] < 0.0);
        // One robot at a time: its own return.
        let mut ret = 0.0;
        let one = scale.scale_one(&mut ret, 2.0, false, 0.9);
        assert!(one > 0.0 && ret == 2.0);
        scale.scale_one(&mut ret, 2.0, true, 0.9);
        assert_eq!(ret, 0.0);
        // A huge reward is clipped.
        let mut fresh = RewardScale::default();
        assert_eq!(fresh.scale(&[1e9], &[false], 0.99), [CLIP]);
    }

    #[test]
    fn a_rollout_stores_scaled_rewards_and_a_saved_model_keeps_the_scaling() {
        use crate::classic::ClassicPendulum;
        use crate::ppo::{Ppo, PpoConfig, RolloutBuffer};
        use twinbots_api::env::VecEnv;

        let mut env = ClassicPendulum::new(4);
        let config = PpoConfig { n_steps: 256, normalize_rewards: true, ..PpoConfig::default() };
        let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 3).unwrap();
        let mut obs = model.observe(&env.reset(Some(3)).unwrap());
        let mut buffer = RolloutBuffer::new(4, env.observation_space().dim(), env.action_space().dim());
        model.collect_rollout(&mut env, &mut obs, &mut buffer).unwrap();
        // Pendulum's costs run to −16 a step (≈ −6 on average at first) and its returns (γ 0.99)
        // to hundreds: scaled, the late steps' costs are small, and still costs. (A truncated
        // episode's last step also holds γ V(final observation): left out.)
        let scale = model.reward_scale.clone().unwrap();
        let std = scale.return_rms.var[0].sqrt();
        assert!(std > 10.0, "the returns' spread {std}");
        let stored: Vec<f32> =
            buffer.rewards.iter().zip(&buffer.dones).filter(|(_, d)| !**d).map(|(r, _)| *r).collect();
        assert!(stored.iter().all(|&r| r <= 0.0));
        let late = &stored[stored.len() - 256..];
        let late_mean = late.iter().map(|r| r.abs()).sum::<f32>() / late.len() as f32;
        assert!(late_mean < 16.5 / std as f32, "late stored rewards average {late_mean}");
        assert_eq!(scale.returns.len(), 4);

        let dir = std::env::temp_dir().join(format!("twinbots-reward-scale-{}", std::process::id()));
        model.save(&dir).unwrap();
        let loaded = Ppo::load(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(loaded.reward_scale, model.reward_scale);
    }
}
