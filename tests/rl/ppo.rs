//! PPO learns.

use twinbots_rl::classic::ClassicCartPole;
use twinbots_rl::{Flow, Ppo, PpoConfig, UpdateStats, VecEnv};

#[test]
fn ppo_reaches_475_on_classic_cartpole_within_150k_steps() {
    let mut env = ClassicCartPole::new(8);
    let mut model = Ppo::new(PpoConfig::zoo_cartpole(), env.observation_space().clone(), env.action_space().clone(), 1).unwrap();
    let mut best = f32::MIN;
    let mut history = Vec::new();
    model
        .learn(&mut env, 150_000, &mut |s: &UpdateStats, _: &Ppo| {
            if s.episodes >= 20 {
                best = best.max(s.mean_reward);
            }
            if s.update % 50 == 0 {
                history.push((s.timesteps, s.mean_reward));
            }
            Ok(if best >= 475.0 { Flow::Stop } else { Flow::Continue })
        })
        .unwrap();
    assert!(best >= 475.0, "best mean reward {best}; history {history:?}");
    assert!(model.timesteps <= 150_000 + 256);
}
