//! PPO with a CNN (`policy = "cnn"`) or keypoints (`policy = "keypoints"`) learns from images:
//! which half of the picture is lit.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_api::{EpisodeSummary, Space, StepResult, VecEnv};
use twinbots_learn::nn::PolicyKind;
use twinbots_learn::{Flow, Learner, OffPolicyConfig, Ppo, PpoConfig, UpdateStats};

/// Each step shows a 36×36 grey image whose left or right half is lit; choosing the lit half
/// (action 0 left, 1 right) earns 1. Episodes of 8 steps. Nothing but the pixels tells which.
struct LitHalf {
    envs: usize,
    space: Space,
    actions: Space,
    rng: ChaCha8Rng,
    lit: Vec<usize>,
    steps: Vec<u32>,
    scores: Vec<f32>,
}

const SIZE: usize = 36;
const LENGTH: u32 = 8;

impl LitHalf {
    fn new(envs: usize) -> Self {
        let space = Space::Image { height: SIZE, width: SIZE, channels: 1 };
        Self {
            envs,
            space,
            actions: Space::Discrete { n: 2 },
            rng: ChaCha8Rng::seed_from_u64(0),
            lit: vec![0; envs],
            steps: vec![0; envs],
            scores: vec![0.0; envs],
        }
    }

    fn observe(&mut self) -> Vec<f32> {
        let mut obs = Vec::with_capacity(self.envs * SIZE * SIZE);
        for i in 0..self.envs {
            self.lit[i] = self.rng.random_range(0..2);
            for _y in 0..SIZE {
                for x in 0..SIZE {
                    let lit = (x >= SIZE / 2) == (self.lit[i] == 1);
                    obs.push(if lit { 230.0 } else { 40.0 } + self.rng.random_range(0..20) as f32);
                }
            }
        }
        obs
    }
}

impl VecEnv for LitHalf {
    fn num_envs(&self) -> usize {
        self.envs
    }
    fn observation_space(&self) -> &Space {
        &self.space
    }
    fn action_space(&self) -> &Space {
        &self.actions
    }
    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        self.steps.fill(0);
        self.scores.fill(0.0);
        Ok(self.observe())
    }
    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        let mut out = StepResult::default();
        for i in 0..self.envs {
            let reward = if actions[i] as usize == self.lit[i] { 1.0 } else { 0.0 };
            self.steps[i] += 1;
            self.scores[i] += reward;
            let ended = self.steps[i] == LENGTH;
            out.rewards.push(reward);
            out.terminated.push(false);
            out.truncated.push(ended);
            out.ended_by.push(None);
            out.episodes.push(ended.then(|| EpisodeSummary {
                score: self.scores[i],
                length: LENGTH,
                ..Default::default()
            }));
            if ended {
                (self.steps[i], self.scores[i]) = (0, 0.0);
            }
        }
        out.obs = self.observe();
        // The final image is as uninformative as any other: the next one stands in for it.
        out.final_obs = out
            .truncated
            .iter()
            .enumerate()
            .map(|(i, &t)| t.then(|| out.obs[i * SIZE * SIZE..(i + 1) * SIZE * SIZE].to_vec()))
            .collect();
        Ok(out)
    }
}

/// Trains `model` for at most `budget` steps, stopping once the mean score of the recent
/// episodes reaches `goal` (counted after `episodes` have ended); returns the best mean seen.
fn learn_until(model: &mut dyn Learner, env: &mut dyn VecEnv, budget: u64, episodes: u64, goal: f32) -> f32 {
    let mut best = f32::MIN;
    model
        .learn(env, budget, &mut |s: &UpdateStats, _: &dyn twinbots_learn::Agent| {
            if s.episodes >= episodes {
                best = best.max(s.mean_reward);
            }
            Ok(if best >= goal { Flow::Stop } else { Flow::Continue })
        })
        .unwrap();
    best
}

/// Trains PPO with `config` on the lit half (guessing scores 4 of 8), then checks that the
/// saved and loaded model acts as the trained one and reads the images; returns the model.
fn learns_the_lit_half_and_loads(config: PpoConfig, name: &str) -> Ppo {
    let mut env = LitHalf::new(4);
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 2).unwrap();
    let best = learn_until(&mut model, &mut env, 20_000, 20, 7.5);
    assert!(best >= 7.5, "{name}: mean score {best} of 8 after {} steps", model.state.timesteps);

    let dir = std::env::temp_dir().join(format!("twinbots-{name}-{}", std::process::id()));
    model.save(&dir).unwrap();
    let loaded = Ppo::load(&dir).unwrap();
    let obs = env.reset(Some(9)).unwrap();
    assert_eq!(model.predict_deterministic(&obs).unwrap(), loaded.predict_deterministic(&obs).unwrap());
    let right: Vec<f32> = env.lit.iter().map(|&l| l as f32).collect();
    assert_eq!(loaded.predict_deterministic(&obs).unwrap(), right, "the loaded {name} policy reads the images");
    std::fs::remove_dir_all(&dir).ok();
    model
}

fn lit_half_settings() -> PpoConfig {
    PpoConfig { n_steps: 32, batch_size: 64, n_epochs: 4, learning_rate: 1e-3, ..PpoConfig::default() }
}

#[test]
fn ppo_with_a_cnn_learns_which_half_of_the_image_is_lit_and_saves_and_loads_it() {
    let model = learns_the_lit_half_and_loads(
        PpoConfig { policy: PolicyKind::Cnn, features_dim: 64, ..lit_half_settings() },
        "cnn",
    );
    assert!(
        model.policy.named_vars().iter().any(|(name, _)| name == "features.3.weight"),
        "NatureCNN's 3 convolutions and dense layer"
    );
}

#[test]
fn ppo_on_keypoints_with_a_value_cnn_of_its_own_learns_which_half_is_lit_and_loads_it() {
    let config = PpoConfig { policy: PolicyKind::Keypoints, share_features_extractor: false, ..lit_half_settings() };
    let model = learns_the_lit_half_and_loads(config, "keypoints");
    let names: Vec<String> = model.policy.named_vars().into_iter().map(|(n, _)| n).collect();
    assert!(names.contains(&"features.2.weight".into()) && names.contains(&"vf_features.2.weight".into()), "{names:?}");
}

#[test]
fn cnn_settings_that_cannot_work_are_errors_naming_the_key() {
    let small = Space::Image { height: 24, width: 64, channels: 3 };
    let discrete = Space::Discrete { n: 2 };
    let cnn = PpoConfig { policy: PolicyKind::Cnn, ..PpoConfig::default() };
    let e = Ppo::new(cnn.clone(), small, discrete.clone(), 0).unwrap_err().to_string();
    assert!(e.contains("ppo.policy = \"cnn\": NatureCNN needs images of at least 36×36"), "{e}");
    let e = Ppo::new(cnn, Space::uniform_box(4, -1.0, 1.0), discrete.clone(), 0).unwrap_err().to_string();
    assert!(e.contains("is not an image"), "{e}");
    let normalized = PpoConfig { normalize_observations: true, ..PpoConfig::default() };
    let e =
        Ppo::new(normalized, Space::Image { height: 40, width: 40, channels: 3 }, discrete, 0).unwrap_err().to_string();
    assert!(e.contains("ppo.normalize_observations = true: camera images"), "{e}");
}

/// Each step shows a 36×36 image with one lit column; the action (one value in [−1, 1]) earns
/// 1 − |a − x|, x the column's place scaled to [−1, 1]. Episodes of 4 steps.
struct LitColumn {
    space: Space,
    actions: Space,
    rng: ChaCha8Rng,
    column: usize,
    steps: u32,
    score: f32,
}

impl LitColumn {
    fn target(&self) -> f32 {
        2.0 * self.column as f32 / (SIZE - 1) as f32 - 1.0
    }

    fn observe(&mut self) -> Vec<f32> {
        self.column = self.rng.random_range(0..SIZE);
        (0..SIZE * SIZE).map(|i| if (i % SIZE).abs_diff(self.column) <= 1 { 250.0 } else { 30.0 }).collect()
    }
}

impl VecEnv for LitColumn {
    fn num_envs(&self) -> usize {
        1
    }
    fn observation_space(&self) -> &Space {
        &self.space
    }
    fn action_space(&self) -> &Space {
        &self.actions
    }
    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        if let Some(seed) = seed {
            self.rng = ChaCha8Rng::seed_from_u64(seed);
        }
        (self.steps, self.score) = (0, 0.0);
        Ok(self.observe())
    }
    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        let reward = 1.0 - (actions[0] - self.target()).abs();
        self.steps += 1;
        self.score += reward;
        let ended = self.steps == 4;
        let episode = ended.then(|| EpisodeSummary { score: self.score, length: 4, ..Default::default() });
        if ended {
            (self.steps, self.score) = (0, 0.0);
        }
        let obs = self.observe();
        Ok(StepResult {
            final_obs: vec![ended.then(|| obs.clone())],
            obs,
            rewards: vec![reward],
            terminated: vec![false],
            truncated: vec![ended],
            episodes: vec![episode],
            ended_by: vec![None],
        })
    }
}

#[test]
fn sac_with_cnns_learns_where_the_lit_column_is() {
    use twinbots_learn::{Sac, SacConfig};
    let space = Space::Image { height: SIZE, width: SIZE, channels: 1 };
    let mut env = LitColumn {
        space,
        actions: Space::uniform_box(1, -1.0, 1.0),
        rng: ChaCha8Rng::seed_from_u64(0),
        column: 0,
        steps: 0,
        score: 0.0,
    };
    let config = SacConfig {
        off_policy: OffPolicyConfig {
            batch_size: 32,
            learning_starts: 200,
            buffer_size: 10_000,
            learning_rate: 1e-3,
            ..Default::default()
        },
        policy: PolicyKind::Cnn,
        features_dim: 32,
        hidden: vec![64],
        log_interval: 200,
        ..SacConfig::default()
    };
    let mut model = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 5).unwrap();
    let names: Vec<String> =
        model.actor.named_vars().into_iter().chain(model.critic.named_vars("critic")).map(|(n, _)| n).collect();
    assert!(
        names.contains(&"actor.features.0.weight".to_string()) && names.contains(&"critic.features.3.bias".to_string()),
        "{names:?}"
    );
    let best = learn_until(&mut model, &mut env, 6_000, 50, 3.0);
    // Acting at random scores about 4 × 1/3.
    assert!(best >= 3.0, "mean score {best} of 4 after {} steps", model.state.timesteps);
    // The replay buffer keeps the images as bytes, and a checkpoint keeps them so.
    let buffer = model.buffer.as_ref().unwrap();
    assert!(matches!(buffer.obs, twinbots_learn::replay_buffer::Rows::Bytes(_)));
    let dir = std::env::temp_dir().join(format!("twinbots-sac-cnn-{}", std::process::id()));
    model.save(&dir).unwrap();
    let loaded = Sac::load(&dir).unwrap();
    assert_eq!(loaded.buffer.as_ref().unwrap(), buffer);
    let obs = env.reset(Some(3)).unwrap();
    assert_eq!(loaded.predict_deterministic(&obs).unwrap(), model.predict_deterministic(&obs).unwrap());
    std::fs::remove_dir_all(&dir).ok();
    let e = Sac::new(
        SacConfig::default(),
        Space::Image { height: 64, width: 64, channels: 3 },
        Space::uniform_box(1, -1.0, 1.0),
        0,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with(
            "sac.buffer_size = 1000000: 1000000 transitions of Image(64×64×3) observations take 23 GiB; at most 16 GiB"
        ),
        "{e}"
    );
}

/// `[ppo] features_from`: a new model's image encoders (the policy's and the value's own) start
/// from the tensors of a file, such as `pixel_probe` saves; a file that does not fit is an error
/// naming the key.
#[test]
fn a_new_model_starts_its_image_encoders_from_features_from() {
    let space = LitHalf::new(1).space;
    let dir = std::env::temp_dir().join(format!("twinbots-features-from-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let donor = Ppo::new(
        PpoConfig { policy: PolicyKind::Keypoints, ..Default::default() },
        space.clone(),
        Space::Discrete { n: 2 },
        7,
    )
    .unwrap();
    let encoder = twinbots_learn::model_io::var_tensors(&donor.policy.encoder.named_vars());
    let file = dir.join("encoder.safetensors");
    twinbots_learn::model_io::save_tensors(&encoder, &file).unwrap();

    let spec = spec_of(&space);
    let algorithm = twinbots_learn::algos::find("ppo").unwrap();
    let new = |from: &std::path::Path| {
        let keys: toml::Table = format!(
            "policy = \"keypoints\"\nshare_features_extractor = false\nfeatures_from = {:?}\n",
            from.display().to_string()
        )
        .parse()
        .unwrap();
        (algorithm.new)(&(algorithm.config)(&keys, 1).unwrap(), &spec, 0)
    };
    new(&file).unwrap().save(&dir.join("model")).unwrap();
    let saved =
        candle_core::safetensors::load(dir.join("model").join("model.safetensors"), &candle_core::Device::Cpu).unwrap();
    for (name, want) in &encoder {
        for prefix in ["", "vf_"] {
            let got = saved[&format!("{prefix}{name}")].flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert_eq!(got, want.flatten_all().unwrap().to_vec1::<f32>().unwrap(), "{prefix}{name} is the file's");
        }
    }
    let missing = dir.join("missing.safetensors");
    let e = format!("{:#}", new(&missing).err().unwrap());
    assert!(e.starts_with(&format!("ppo.features_from = {}", missing.display())), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A task of `space` and two actions, as the ALGOS table's `new` takes it.
fn spec_of(space: &Space) -> twinbots_api::TaskSpec {
    twinbots_api::TaskSpec {
        name: "lit-half".into(),
        observation_space: space.clone(),
        action_space: Space::Discrete { n: 2 },
        solved: None,
        observation_names: (0..space.dim()).map(|i| format!("obs_{i}")).collect(),
        reward_terms: vec!["lit".into()],
        termination_terms: vec![],
        reward_range: (0.0, 1.0),
        observation_plausible: space.clone(),
        goal: None,
    }
}

/// `[ppo] freeze_features`: the image encoders (the policy's and the value's own) keep every
/// weight through training while the MLPs learn, here on a random CNN's features, which the
/// rollout keeps for the update; asked of a model without an image encoder, it is an error
/// naming the key.
#[test]
fn frozen_image_encoders_keep_their_weights_while_the_mlps_learn() {
    let mut env = LitHalf::new(4);
    let config = PpoConfig {
        policy: PolicyKind::Cnn,
        features_dim: 64,
        share_features_extractor: false,
        freeze_features: true,
        ..lit_half_settings()
    };
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 2).unwrap();
    let weights = |m: &Ppo| -> Vec<(String, Vec<f32>)> {
        m.policy
            .named_vars()
            .into_iter()
            .map(|(n, v)| (n, v.as_tensor().flatten_all().unwrap().to_vec1().unwrap()))
            .collect()
    };
    let before = weights(&model);
    let best = learn_until(&mut model, &mut env, 20_000, 20, 7.5);
    assert!(best >= 7.5, "mean score {best} of 8 after {} steps", model.state.timesteps);
    let frozen = |name: &str| name.starts_with("features.") || name.starts_with("vf_features.");
    assert_eq!(before.iter().filter(|(n, _)| frozen(n)).count(), 16, "both NatureCNNs' variables");
    for ((name, was), (_, now)) in before.iter().zip(&weights(&model)) {
        assert_eq!(was == now, frozen(name), "{name}: frozen {}", frozen(name));
    }

    // The rollout keeps the features it acted on, so an update reads them instead of running
    // the CNNs again: they are the encoders' features of the stored images.
    let mut obs = model.observe(&env.reset(Some(3)).unwrap());
    let mut buffer = twinbots_learn::ppo::RolloutBuffer::new(4, SIZE * SIZE, 1);
    model.collect_rollout(&mut env, &mut obs, &mut buffer).unwrap();
    assert_eq!((buffer.cached_width(&buffer.features), buffer.cached_width(&buffer.value_features)), (64, 64));
    let images =
        candle_core::Tensor::from_slice(&buffer.obs, (buffer.len(), SIZE * SIZE), &candle_core::Device::Cpu).unwrap();
    let (features, value_features) = model.policy.features(&images).unwrap();
    for (cached, computed) in [(&buffer.features, features), (&buffer.value_features, value_features.unwrap())] {
        let computed: Vec<f32> = computed.flatten_all().unwrap().to_vec1().unwrap();
        let off = cached.iter().zip(&computed).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(off < 1e-4, "cached features off by {off}");
    }

    let flat = Space::uniform_box(4, -1.0, 1.0);
    let algorithm = twinbots_learn::algos::find("ppo").unwrap();
    let keys: toml::Table = "freeze_features = true".parse().unwrap();
    let e = format!("{:#}", (algorithm.new)(&(algorithm.config)(&keys, 1).unwrap(), &spec_of(&flat), 0).err().unwrap());
    assert!(e.starts_with("ppo.freeze_features = true: there is no image encoder"), "{e}");
}
