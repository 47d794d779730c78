//! The settings' resolution and checks.

use rand::{Rng, SeedableRng};
use twinbots_learn::{OffPolicyConfig, SacConfig};

use super::*;

#[test]
fn sac_settings_resolve_from_the_robots_sac_defaults_key_by_key_and_refuse_what_sac_cannot_do() {
    let ur5e = crate::registry::find("ur5e").unwrap();
    let file: ConfigFile = toml::from_str("algo = \"sac\"\n[sac]\nbatch_size = 128\n").unwrap();
    let s = TrainSettings::resolve(&ur5e, file, ConfigFile::default()).unwrap();
    let defaults = ur5e.defaults.of("sac");
    assert_eq!(
        (s.algo.as_str(), s.arenas, s.timesteps, s.eval_every),
        ("sac", defaults.arenas, defaults.timesteps, defaults.eval_every)
    );
    let tuned: SacConfig = defaults.config().unwrap();
    assert_eq!(
        s.config_of::<SacConfig>("sac").unwrap(),
        SacConfig { off_policy: OffPolicyConfig { batch_size: 128, ..tuned.off_policy.clone() }, ..tuned },
        "a [sac] key replaced more than itself"
    );
    let flags = ConfigFile { algo: Some("ppo".into()), ..Default::default() };
    let file: ConfigFile = toml::from_str("algo = \"sac\"\n").unwrap();
    assert_eq!(TrainSettings::resolve(&ur5e, file, flags).unwrap().algo, "ppo", "the flag did not win");

    let sac = || ConfigFile { algo: Some("sac".into()), ..Default::default() };
    let cartpole = crate::registry::find("cartpole").unwrap();
    let err = TrainSettings::resolve(&cartpole, sac(), ConfigFile::default()).unwrap_err().to_string();
    assert!(err.contains("algo = sac") && err.contains("Box"), "{err}");
    let pattern3 = ConfigFile { pattern: Some(3), ..Default::default() };
    // The RobotServer trains SAC too (its line of the table says it `serves`).
    assert_eq!(TrainSettings::resolve(&ur5e, sac(), pattern3).unwrap().algo, "sac");
    let file: ConfigFile = toml::from_str("[sac]\ntau = 2.0\n").unwrap();
    let err = TrainSettings::resolve(&ur5e, file, sac()).unwrap_err().to_string();
    assert!(err.starts_with("sac.tau = 2"), "{err}");
}

/// Every key a config file may hold, with the kind of value it takes.
const KEYS: &[&str] = &[
    "task",
    "timesteps",
    "arenas",
    "seed",
    "pattern",
    "checkpoint_every",
    "eval_every",
    "eval_episodes",
    "ppo.learning_rate",
    "ppo.linear_lr",
    "ppo.n_steps",
    "ppo.batch_size",
    "ppo.n_epochs",
    "ppo.gamma",
    "ppo.gae_lambda",
    "ppo.clip_range",
    "ppo.ent_coef",
    "ppo.vf_coef",
    "ppo.max_grad_norm",
    "ppo.target_kl",
    "ppo.normalize_advantage",
    "ppo.normalize_observations",
    "ppo.hidden",
    "ppo.log_std_init",
    "ppo.no_such_key",
    "algo",
    "sac.learning_rate",
    "sac.buffer_size",
    "sac.learning_starts",
    "sac.batch_size",
    "sac.tau",
    "sac.gamma",
    "sac.train_freq",
    "sac.gradient_steps",
    "sac.learn_ent_coef",
    "sac.ent_coef_init",
    "sac.target_entropy",
    "sac.target_update_interval",
    "sac.hidden",
    "sac.normalize_observations",
    "sac.log_interval",
    "sac.her_goals",
    "sac.typo",
    "randomization.start_window",
    "randomization.action_probability",
    "randomization.mass_scale",
    "randomization.friction",
    "randomization.motor_strength",
    "randomization.sensor_noise",
    "randomization.action_latency",
    "randomization.typo",
    "randomization.visual.lights",
    "randomization.visual.light_intensity",
    "randomization.visual.field_of_view",
    "randomization.visual.ambient",
    "randomization.visual.textures",
    "randomization.visual.typo",
];
const VALUES: &[&str] = &[
    "0",
    "1",
    "-1",
    "2",
    "3",
    "64",
    "4096",
    "4097",
    "18446744073709551615",
    "-9223372036854775808",
    "0.5",
    "1e-300",
    "1e300",
    "1e39",
    "nan",
    "inf",
    "-inf",
    "true",
    "\"x\"",
    "[]",
    "[0]",
    "[64, 64]",
    "[1.0, 0.5]",
    "[0.5, 1.0]",
    "[0, inf]",
    "[nan, 1]",
    "[1, 2, 3]",
    "[100000000, 1]",
    "{}",
    "\"sac\"",
    "\"ppo\"",
    "\"balance\"",
];

/// Random config files made of real keys and hostile values: every one resolves to valid
/// settings or to an error naming a key, and none panics.
#[test]
fn no_config_file_panics_and_every_refusal_names_its_key() {
    let entry = crate::registry::find("cartpole").unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    let (mut accepted, mut refused) = (0, 0);
    for _ in 0..20_000 {
        let mut tables: std::collections::BTreeMap<&str, Vec<String>> = Default::default();
        for _ in 0..rng.random_range(1..4) {
            let key = KEYS[rng.random_range(0..KEYS.len())];
            let value = VALUES[rng.random_range(0..VALUES.len())];
            let (table, name) = key.split_once('.').unwrap_or(("", key));
            tables.entry(table).or_default().push(format!("{name} = {value}"));
        }
        let mut text = String::new();
        for (table, lines) in &tables {
            if !table.is_empty() {
                text += &format!("[{table}]\n");
            }
            for line in lines {
                text += line;
                text.push('\n');
            }
        }
        let outcome =
            ConfigFile::parse(&text).and_then(|file| TrainSettings::resolve(&entry, file, ConfigFile::default()));
        match outcome {
            Ok(settings) => {
                settings.validate().unwrap();
                accepted += 1;
            }
            Err(e) => {
                let message = format!("{e:#}");
                let named = KEYS.iter().any(|k| message.contains(k.rsplit('.').next().unwrap()))
                    || message.contains("duplicate key");
                assert!(named, "{text:?} was refused without naming a key: {message}");
                refused += 1;
            }
        }
    }
    assert!(accepted > 800 && refused > 1000, "{accepted} accepted, {refused} refused: the values are not a mix");
}
