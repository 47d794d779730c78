//! SAC learns, saves, loads and resumes.

use std::time::Instant;

use twinbots_api::VecEnv;
use twinbots_learn::classic::ClassicPendulum;
use twinbots_learn::{Agent, Flow, Learner, OffPolicyConfig, Sac, SacConfig, UpdateStats};

/// SB3's SAC defaults but for 64-unit layers (256 cost 16× the arithmetic: a gradient step took
/// ~50 ms on the 2-core CI machine), on the analytic Pendulum-v1 (SB3 reaches about −150 in
/// 20 k steps).
#[test]
fn sac_reaches_minus_200_on_pendulum_within_20k_steps() {
    let mut env = ClassicPendulum::new(1);
    let config = SacConfig { hidden: vec![64, 64], ..SacConfig::default() };
    let mut model = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 0).unwrap();
    reaches_minus_200_on_pendulum(&mut model, &mut env);
}

/// Trains `model` 20 k steps on `env` (the analytic Pendulum-v1), its progress on stderr, and
/// asserts that the last 10 training episodes (the window holds the last 100: judge the recent
/// ones) average −200 or better. SAC's test and TD3's.
pub fn reaches_minus_200_on_pendulum(model: &mut dyn Learner, env: &mut ClassicPendulum) {
    let started = Instant::now();
    let mut rows = Vec::new();
    model
        .learn(env, 20_000, &mut |s: &UpdateStats, _: &dyn Agent| {
            rows.push((s.timesteps, s.mean_reward, s.train("actor_loss"), s.train("critic_loss")));
            eprintln!(
                "{} steps: mean {:.0}, actor {:.2}, critic {:.3} ({:.0} s)",
                s.timesteps,
                s.mean_reward,
                s.train("actor_loss"),
                s.train("critic_loss"),
                started.elapsed().as_secs_f32()
            );
            Ok(Flow::Continue)
        })
        .unwrap();
    assert_eq!(model.state().timesteps, 20_000);
    let recent: Vec<f32> = model.state().history.recent_scores.iter().rev().take(10).copied().collect();
    let mean = recent.iter().sum::<f32>() / recent.len() as f32;
    assert!(mean >= -200.0, "mean of the last 10 episodes {mean}; rows {rows:?}");
}

fn small_pendulum_model(steps: u64) -> (Sac, ClassicPendulum) {
    let mut env = ClassicPendulum::new(2);
    let config = SacConfig {
        off_policy: OffPolicyConfig { learning_starts: 100, batch_size: 32, ..Default::default() },
        hidden: vec![16, 16],
        log_interval: 100,
        ..SacConfig::default()
    };
    let mut model = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 4).unwrap();
    model.learn(&mut env, steps, &mut |_: &UpdateStats, _: &dyn Agent| Ok(Flow::Continue)).unwrap();
    (model, env)
}

fn weights(dir: &std::path::Path) -> Vec<u8> {
    std::fs::read(dir.join("model.safetensors")).unwrap()
}

#[test]
fn a_saved_sac_model_loads_as_it_was_and_learns_on_alike() {
    let (mut model, mut env) = small_pendulum_model(600);
    let dir = std::env::temp_dir().join(format!("twinbots-sac-save-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    model.save(&dir).unwrap();
    let mut loaded = Sac::load(&dir).unwrap();
    assert_eq!(loaded.state.timesteps, 600);
    assert_eq!(loaded.buffer, model.buffer, "the replay buffer did not come back");
    assert_eq!(loaded.state.history, model.state.history);
    let obs = [0.3f32, -0.9, 1.5, 1.0, 0.0, -4.0];
    assert_eq!(loaded.predict_deterministic(&obs).unwrap(), model.predict_deterministic(&obs).unwrap());
    assert_eq!(
        loaded.predict(&obs, false).unwrap(),
        model.predict(&obs, false).unwrap(),
        "the sampling stream differs"
    );
    // Both go on from the same env: every gradient step (optimisers, targets, α) alike.
    let mut env2 = ClassicPendulum::new(2);
    let obs_now = env.reset(Some(9)).unwrap();
    assert_eq!(env2.reset(Some(9)).unwrap(), obs_now);
    model.learn(&mut env, 300, &mut |_: &UpdateStats, _: &dyn Agent| Ok(Flow::Continue)).unwrap();
    loaded.learn(&mut env2, 300, &mut |_: &UpdateStats, _: &dyn Agent| Ok(Flow::Continue)).unwrap();
    let (a, b) = (dir.join("a"), dir.join("b"));
    model.save(&a).unwrap();
    loaded.save(&b).unwrap();
    assert!(weights(&a) == weights(&b), "the loaded model learnt differently");
    for file in ["optimizer.safetensors", "replay_buffer.safetensors", "model.json"] {
        assert!(std::fs::read(a.join(file)).unwrap() == std::fs::read(b.join(file)).unwrap(), "{file} differs");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn damaged_sac_files_are_named_and_a_ppo_loader_refuses_a_sac_model() {
    let (model, _) = small_pendulum_model(200);
    let dir = std::env::temp_dir().join(format!("twinbots-sac-damaged-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    model.save(&dir).unwrap();
    let err = twinbots_learn::Ppo::load(&dir).unwrap_err().to_string();
    assert!(err.contains("a SAC model, not PPO"), "{err}");
    assert_eq!(twinbots_learn::load_agent(&dir).unwrap().algorithm(), "SAC");
    std::fs::write(dir.join("replay_buffer.safetensors"), b"not a buffer").unwrap();
    let err = Sac::load(&dir).unwrap_err().to_string();
    assert!(err.contains("replay_buffer.safetensors"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn sac_refuses_discrete_actions_and_a_her_option_without_a_goal() {
    let env = twinbots_learn::classic::ClassicCartPole::new(1);
    let err = Sac::new(SacConfig::default(), env.observation_space().clone(), env.action_space().clone(), 0)
        .unwrap_err()
        .to_string();
    assert!(err.contains("continuous (Box) actions"), "{err}");
    let env = ClassicPendulum::new(1);
    let her = SacConfig { her_goals: 4, ..SacConfig::default() };
    let err = Sac::new(her, env.observation_space().clone(), env.action_space().clone(), 0)
        .unwrap()
        .with_goal(None)
        .unwrap_err()
        .to_string();
    assert!(err.contains("sac.her_goals = 4"), "{err}");
}
