//! The exported ONNX graph acts as the model does: run by tract on 1,000 random observations,
//! its actions equal the model's own deterministic ones (to 1e-5; discrete choices identical)
//! for a discrete, a continuous and a normalised-observation PPO policy, a SAC policy and cloned
//! (BC) policies of both kinds; and
//! PPO and SAC policies on camera images (NatureCNN and keypoints) to 1e-4. Bad files are clear
//! errors.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_api::{Space, VecEnv};
use twinbots_learn::classic::{ClassicCartPole, ClassicPendulum};
use twinbots_learn::nn::PolicyKind;
use twinbots_learn::normalize::RunningMeanStd;
use twinbots_learn::{Agent, Bc, BcConfig, Flow, OffPolicyConfig, Ppo, PpoConfig, Sac, SacConfig};
use twinbots_onnx::{OnnxPolicy, PolicyMetadata};

const OBSERVATIONS: usize = 1000;

fn metadata(agent: &dyn Agent) -> PolicyMetadata {
    PolicyMetadata {
        twinbots_version: "test".into(),
        robot: "test".into(),
        task: "test".into(),
        design_pattern: 1,
        observation_space: agent.observation_space().clone(),
        observation_names: (0..agent.observation_space().dim()).map(|i| format!("x{i}")).collect(),
        action_space: agent.action_space().clone(),
        control_period_s: 0.02,
        normalizes_observations: agent.policy_net().unwrap().obs_rms.is_some(),
        timesteps: agent.timesteps(),
    }
}

fn trained(env: &mut dyn VecEnv, config: PpoConfig, steps: u64) -> Ppo {
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 5).unwrap();
    model.learn(env, steps, &mut |_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)).unwrap();
    model
}

/// Rows of observations around `scale`, a few far out (beyond the normaliser's ±10 clip).
fn observations(dim: usize, scale: f32, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..OBSERVATIONS * dim)
        .map(|i| {
            let far = if i % 97 == 0 { 50.0 } else { 1.0 };
            rng.random_range(-1.0f32..1.0) * scale * far
        })
        .collect()
}

/// The exported graph's actions and the model's on the same observations.
fn both(model: &dyn Agent, obs: &[f32]) -> (Vec<f32>, Vec<f32>) {
    let bytes = twinbots_onnx::policy_bytes(model, &metadata(model)).unwrap();
    let policy = OnnxPolicy::from_bytes(&bytes).unwrap();
    (policy.act(obs).unwrap(), model.predict_deterministic(obs).unwrap())
}

fn largest_difference(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

#[test]
fn a_discrete_policy_makes_the_same_choices() {
    let config = PpoConfig { n_steps: 128, ..Default::default() };
    let model = trained(&mut ClassicCartPole::new(4), config, 2048);
    let obs = observations(4, 2.0, 1);
    let (onnx, own) = both(&model, &obs);
    let differ = onnx.iter().zip(&own).filter(|(a, b)| a != b).count();
    eprintln!("discrete: {differ} of {OBSERVATIONS} choices differ; max |Δ| {}", largest_difference(&onnx, &own));
    assert_eq!(differ, 0);
    assert!(own.contains(&0.0) && own.contains(&1.0), "both choices occur, so the comparison means something");
}

#[test]
fn a_continuous_policy_gives_the_same_clipped_actions() {
    // A box with different bounds per dimension, and an output layer made 100 times larger
    // than initialised so that a good share of actions fall outside the box and are clipped.
    let action_space = Space::Box { low: vec![-1.0, -2.0, 0.0], high: vec![1.0, 0.5, 3.0] };
    let model = Ppo::new(PpoConfig::default(), Space::uniform_box(6, -5.0, 5.0), action_space.clone(), 9).unwrap();
    for (name, var) in model.policy.named_vars() {
        if name == "pi.2.weight" {
            var.set(&var.as_tensor().affine(100.0, 0.0).unwrap()).unwrap();
        }
    }
    let obs = observations(6, 3.0, 2);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("continuous: max |Δ| {delta:e} over {OBSERVATIONS} observations");
    assert!(delta <= 1e-5, "max |Δ| {delta}");
    assert!(action_space.contains(&onnx[..3]));
    let Space::Box { low, high } = &action_space else { unreachable!() };
    let clipped = own.iter().enumerate().filter(|(i, a)| **a == low[i % 3] || **a == high[i % 3]).count();
    assert!(clipped > OBSERVATIONS / 10, "only {clipped} actions were clipped");
}

#[test]
fn a_normalised_observation_policy_folds_its_statistics_in() {
    let config = PpoConfig { n_steps: 128, normalize_observations: true, ..Default::default() };
    let model = trained(&mut ClassicPendulum::new(4), config, 2048);
    let rms = model.state.obs_rms.as_ref().expect("a normalising model");
    assert!(rms.mean.iter().any(|m| m.abs() > 0.05), "statistics moved from their start: {:?}", rms.mean);
    let obs = observations(3, 4.0, 3);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("normalised observations: max |Δ| {delta:e} over {OBSERVATIONS} observations");
    assert!(delta <= 1e-5, "max |Δ| {delta}");
    let normalised = model.normalize(&obs);
    assert!(normalised.iter().any(|x| x.abs() == 10.0), "some observations reach the ±10 clip");
}

#[test]
fn a_sac_policy_gives_the_same_squashed_and_rescaled_actions() {
    // A box with different bounds per dimension, observation statistics folded in, and a mean
    // head made 20 times larger than initialised so that many actions lie near the box's
    // bounds, where tanh saturates.
    let action_space = Space::Box { low: vec![-1.0, -2.0, 0.0], high: vec![1.0, 0.5, 3.0] };
    let config = SacConfig { hidden: vec![32, 32], normalize_observations: true, ..Default::default() };
    let mut model = Sac::new(config, Space::uniform_box(6, -5.0, 5.0), action_space.clone(), 11).unwrap();
    model.state.obs_rms = Some(RunningMeanStd {
        mean: vec![0.5, -1.0, 0.0, 2.0, 0.1, -0.3],
        var: vec![4.0, 0.25, 1.0, 9.0, 0.01, 2.0],
        count: 1e4,
    });
    for (name, var) in model.actor.named_vars() {
        if name == "actor.mu.weight" {
            var.set(&var.as_tensor().affine(20.0, 0.0).unwrap()).unwrap();
        }
    }
    let obs = observations(6, 3.0, 4);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("SAC: max |Δ| {delta:e} over {OBSERVATIONS} observations");
    assert!(delta <= 1e-5, "max |Δ| {delta}");
    assert!(onnx.chunks(3).all(|a| action_space.contains(a)), "every action lies in the box");
    let Space::Box { low, high } = &action_space else { unreachable!() };
    let near_bounds = own.iter().enumerate().filter(|(i, a)| (**a - low[i % 3]).min(high[i % 3] - **a) < 0.01).count();
    assert!(near_bounds > OBSERVATIONS / 10, "only {near_bounds} actions lie near the bounds");
}

#[test]
fn cloned_policies_export_their_squashed_and_arg_max_heads() {
    // Continuous: the demonstrations' statistics folded in, a head made 20 times larger so that
    // many actions lie near the box's bounds. Discrete: the arg max of the logits.
    let action_space = Space::Box { low: vec![-1.0, -2.0, 0.0], high: vec![1.0, 0.5, 3.0] };
    let config = BcConfig { hidden: vec![32, 32], ..Default::default() };
    let mut model = Bc::new(config.clone(), Space::uniform_box(6, -5.0, 5.0), action_space.clone(), 13).unwrap();
    model.state.obs_rms = Some(RunningMeanStd {
        mean: vec![0.5, -1.0, 0.0, 2.0, 0.1, -0.3],
        var: vec![4.0, 0.25, 1.0, 9.0, 0.01, 2.0],
        count: 1e4,
    });
    let last = &model.policy.layers.last().unwrap().weight;
    last.set(&last.as_tensor().affine(20.0, 0.0).unwrap()).unwrap();
    let obs = observations(6, 3.0, 5);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("BC: max |Δ| {delta:e} over {OBSERVATIONS} observations");
    assert!(delta <= 1e-5, "max |Δ| {delta}");
    assert!(onnx.chunks(3).all(|a| action_space.contains(a)), "every action lies in the box");

    let cartpole = ClassicCartPole::new(1);
    let model = Bc::new(config, cartpole.observation_space().clone(), Space::Discrete { n: 3 }, 14).unwrap();
    let (onnx, own) = both(&model, &observations(4, 2.0, 6));
    assert_eq!(onnx, own);
    let choices: std::collections::BTreeSet<u32> = own.iter().map(|&a| a as u32).collect();
    assert!(choices.len() >= 2, "more than one choice occurs, so the comparison means something: {choices:?}");
}

/// Rows of camera images: 0–255 values, some regions bright, as the env hands them over.
fn images(space: &Space, rows: usize, seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..rows * space.dim()).map(|_| rng.random_range(0u8..=255) as f32).collect()
}

#[test]
fn policies_on_camera_images_export_their_cnn() {
    let image = Space::Image { height: 40, width: 44, channels: 6 };
    let action_space = Space::Box { low: vec![-1.0, -2.0], high: vec![1.0, 0.5] };
    let rows = 200;
    let obs = images(&image, rows, 6);

    let config = PpoConfig { features_dim: 24, ..Default::default() };
    let model = Ppo::new(config, image.clone(), action_space.clone(), 12).unwrap();
    // A larger output layer, so that actions spread over the box and beyond it.
    for (name, var) in model.policy.named_vars() {
        if name == "pi.2.weight" {
            var.set(&var.as_tensor().affine(1000.0, 0.0).unwrap()).unwrap();
        }
    }
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("PPO on images: max |Δ| {delta:e} over {rows} images");
    assert!(delta <= 1e-4, "max |Δ| {delta}");
    let spread = own.iter().map(|a| a.abs()).fold(0.0f32, f32::max);
    assert!(spread > 0.5, "the actions vary, so the comparison means something: {spread}");

    let config = SacConfig {
        off_policy: OffPolicyConfig { buffer_size: 1000, ..Default::default() },
        hidden: vec![32],
        features_dim: 24,
        ..Default::default()
    };
    let model = Sac::new(config, image.clone(), action_space.clone(), 13).unwrap();
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("SAC on images: max |Δ| {delta:e} over {rows} images");
    assert!(delta <= 1e-4, "max |Δ| {delta}");

    // An image and state values: the graph slices them apart and joins the state to the features.
    let with_state =
        Space::ImageAndState { height: 40, width: 44, channels: 6, low: vec![-300.0; 5], high: vec![300.0; 5] };
    let obs = images(&with_state, rows, 7);
    let config = SacConfig {
        off_policy: OffPolicyConfig { buffer_size: 1000, ..Default::default() },
        hidden: vec![32],
        features_dim: 24,
        ..Default::default()
    };
    let model = Sac::new(config, with_state.clone(), action_space, 14).unwrap();
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("SAC on an image and state: max |Δ| {delta:e} over {rows} observations");
    assert!(delta <= 1e-4, "max |Δ| {delta}");
    let moved: Vec<f32> =
        obs.chunks(with_state.dim()).flat_map(|o| [&o[..o.len() - 5], &[299.0; 5][..]].concat()).collect();
    assert_ne!(both(&model, &moved).1, own, "the state values reach the actions");
}

/// Multiplies the variables whose names end with `suffix` by `factor`.
fn scale_vars(vars: Vec<(String, candle_core::Var)>, suffix: &str, factor: f64) {
    for (_, var) in vars.into_iter().filter(|(name, _)| name.ends_with(suffix)) {
        var.set(&var.as_tensor().affine(factor, 0.0).unwrap()).unwrap();
    }
}

#[test]
fn keypoint_policies_export_their_spatial_softmax() {
    // The camera reach's form: a 64×64 image and state values, PPO with a value CNN of its own
    // (left out of the graph), and SAC on the image alone. The last convolution is scaled up so
    // each map's softmax sits on a few pixels: keypoints spread over the image, and a grid
    // read in the wrong order would move them.
    let action_space = Space::Box { low: vec![-1.0, -2.0], high: vec![1.0, 0.5] };
    let rows = 100;
    let with_state =
        Space::ImageAndState { height: 64, width: 64, channels: 3, low: vec![-3.0; 5], high: vec![3.0; 5] };
    let obs = images(&with_state, rows, 8);
    let config = PpoConfig { policy: PolicyKind::Keypoints, share_features_extractor: false, ..Default::default() };
    let model = Ppo::new(config, with_state.clone(), action_space.clone(), 15).unwrap();
    scale_vars(model.policy.named_vars(), "features.2.weight", 30.0);
    scale_vars(model.policy.named_vars(), "pi.2.weight", 300.0);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("PPO on keypoints and state: max |Δ| {delta:e} over {rows} observations");
    assert!(delta <= 1e-4, "max |Δ| {delta}");
    let spread = own.iter().map(|a| a.abs()).fold(0.0f32, f32::max);
    assert!(spread > 0.5, "the actions vary, so the comparison means something: {spread}");

    let image = Space::Image { height: 48, width: 40, channels: 3 };
    let obs = images(&image, rows, 9);
    let config = SacConfig {
        off_policy: OffPolicyConfig { buffer_size: 1000, ..Default::default() },
        policy: PolicyKind::Keypoints,
        hidden: vec![32],
        ..Default::default()
    };
    let model = Sac::new(config, image, action_space, 16).unwrap();
    scale_vars(model.actor.named_vars(), "features.2.weight", 30.0);
    let (onnx, own) = both(&model, &obs);
    let delta = largest_difference(&onnx, &own);
    eprintln!("SAC on keypoints: max |Δ| {delta:e} over {rows} images");
    assert!(delta <= 1e-4, "max |Δ| {delta}");
}

#[test]
fn files_that_are_not_policies_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("twinbots-onnx-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = dir.join("notes.onnx");
    std::fs::write(&text, "this is not a protobuf at all, just text\n").unwrap();
    let err = format!("{:#}", OnnxPolicy::load(&text).unwrap_err());
    assert!(err.contains("notes.onnx") && err.contains("not an ONNX model"), "{err}");
    let empty = dir.join("empty.onnx");
    std::fs::write(&empty, b"").unwrap();
    let err = format!("{:#}", OnnxPolicy::load(&empty).unwrap_err());
    assert!(err.contains("not an ONNX model (no graph)"), "{err}");
    // An ONNX model without twinbots' description.
    let model = Ppo::new(PpoConfig::default(), Space::uniform_box(2, -1.0, 1.0), Space::Discrete { n: 2 }, 0).unwrap();
    let mut proto = twinbots_onnx::policy_model(&model, &metadata(&model)).unwrap();
    proto.metadata_props.clear();
    let err = format!("{:#}", OnnxPolicy::from_bytes(&prost::Message::encode_to_vec(&proto)).unwrap_err());
    assert_eq!(err, "not a twinbots policy: no metadata 'twinbots.version'");
    let err = format!("{:#}", OnnxPolicy::load(&dir.join("missing.onnx")).unwrap_err());
    assert!(err.contains("missing.onnx"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
