//! The model lifecycle: save/load round trips exactly; spaces are checked.

use twinbots_api::{Space, VecEnv};
use twinbots_learn::classic::ClassicCartPole;
use twinbots_learn::{Ppo, PpoConfig};

pub fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn load_of_save_predicts_exactly_as_the_original() {
    let mut env = ClassicCartPole::new(4);
    let config = PpoConfig { n_steps: 64, normalize_observations: true, ..Default::default() };
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 3).unwrap();
    model.learn(&mut env, 512, &mut |_: &_, _: &dyn twinbots_learn::Agent| Ok(twinbots_learn::Flow::Continue)).unwrap();
    let dir = temp_dir("model");
    model.save(&dir).unwrap();
    let mut loaded = Ppo::load(&dir).unwrap();
    let obs = env.reset(Some(9)).unwrap();
    assert_eq!(model.predict(&obs, true).unwrap(), loaded.predict(&obs, true).unwrap());
    assert_eq!(loaded.state.timesteps, model.state.timesteps);
    assert_eq!(loaded.state.obs_rms, model.state.obs_rms, "normalisation travels with the model");
    // Stochastic predictions match too once both streams start from the same point.
    let a = Ppo::load(&dir).unwrap().predict(&obs, false).unwrap();
    let b = Ppo::load(&dir).unwrap().predict(&obs, false).unwrap();
    assert_eq!(a, b);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_snapshot_predicts_as_the_original_and_does_not_train_with_it() {
    let mut env = ClassicCartPole::new(4);
    let config = PpoConfig { n_steps: 64, normalize_observations: true, ..Default::default() };
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 3).unwrap();
    model.learn(&mut env, 512, &mut |_: &_, _: &dyn twinbots_learn::Agent| Ok(twinbots_learn::Flow::Continue)).unwrap();
    let mut snapshot = model.snapshot().unwrap();
    let obs = env.reset(Some(9)).unwrap();
    assert_eq!(
        snapshot.predict(&obs, false).unwrap(),
        model.predict(&obs, false).unwrap(),
        "same weights, same stream"
    );
    assert_eq!(
        (snapshot.state.timesteps, snapshot.state.updates, &snapshot.state.obs_rms),
        (model.state.timesteps, model.state.updates, &model.state.obs_rms)
    );
    let weights = |m: &Ppo| -> Vec<Vec<f32>> {
        m.policy.named_vars().iter().map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap()).collect()
    };
    let before = weights(&snapshot);
    model.learn(&mut env, 512, &mut |_: &_, _: &dyn twinbots_learn::Agent| Ok(twinbots_learn::Flow::Continue)).unwrap();
    assert_ne!(weights(&model), before, "the original trained on");
    assert_eq!(weights(&snapshot), before, "the snapshot shares no variable with it");
}

#[test]
fn a_model_for_other_spaces_is_a_clear_error() {
    let env = ClassicCartPole::new(1);
    let model = Ppo::new(PpoConfig::default(), env.observation_space().clone(), env.action_space().clone(), 0).unwrap();
    let err = model
        .check_spaces(&Space::uniform_box(4, -1.0, 1.0), &Space::uniform_box(1, -6.4, 6.4))
        .unwrap_err()
        .to_string();
    assert!(err.contains("Discrete(2)") && err.contains("Box(1)"), "{err}");
    let err = model.check_spaces(&Space::uniform_box(5, -1.0, 1.0), &Space::Discrete { n: 2 }).unwrap_err().to_string();
    assert!(err.contains('4') && err.contains('5'), "{err}");
}

#[test]
fn loading_a_missing_or_corrupt_model_names_the_file() {
    let dir = temp_dir("corrupt");
    let err = Ppo::load(&dir).unwrap_err().to_string();
    assert!(err.contains("model.json"), "{err}");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("model.json"), "{ not json").unwrap();
    let err = Ppo::load(&dir).unwrap_err().to_string();
    assert!(err.contains("model.json"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
