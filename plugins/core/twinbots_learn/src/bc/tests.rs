use super::*;
use crate::callbacks::CallbackList;
use crate::classic::ClassicCartPole;
use crate::evaluation::evaluate_policy;
use twinbots_dataset::{DatasetSpec, DatasetWriter, Episode, Frame};

/// A hand-written cart-pole controller that balances every episode for 500 steps: push
/// towards where the pole (and, less, the cart) leans.
fn scripted(s: &[f32]) -> f32 {
    f32::from(u8::from(s[2] + 0.5 * s[3] + 0.05 * s[0] + 0.1 * s[1] > 0.0))
}

/// `episodes` episodes of the scripted controller on CartPole-v1, written as a LeRobot dataset
/// under `root`.
fn cartpole_demos(root: &Path, episodes: u64) -> std::path::PathBuf {
    let out = root.join("demos");
    let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect();
    let spec = DatasetSpec {
        robot: "cartpole".into(),
        fps: 50.0,
        state_names: names(&["x", "x_dot", "theta", "theta_dot"]),
        action_names: names(&["push"]),
        cameras: Vec::new(),
    };
    let mut writer = DatasetWriter::new(&out, spec).unwrap();
    let mut env = ClassicCartPole::new(1);
    for seed in 0..episodes {
        let mut obs = env.reset(Some(seed)).unwrap();
        let mut frames = Vec::new();
        loop {
            let action = scripted(&obs);
            let step = env.step(&[action]).unwrap();
            let done = step.terminated[0] || step.truncated[0];
            frames.push(Frame {
                state: obs.clone(),
                action: vec![action],
                reward: 1.0,
                done,
                success: false,
                images: Vec::new(),
            });
            obs = step.obs;
            if done {
                break;
            }
        }
        writer.add(Episode { task: "balance".into(), seed, frames }).unwrap();
    }
    writer.finish().unwrap();
    out
}

fn cartpole_bc(demos: &Path, seed: u64) -> Bc {
    let env = ClassicCartPole::new(1);
    let config = BcConfig { demos: demos.display().to_string(), ..BcConfig::default() };
    Bc::new(config, env.observation_space().clone(), env.action_space().clone(), seed).unwrap()
}

#[test]
fn a_policy_cloned_from_a_scripted_controller_balances_the_pole_and_resumes_exactly() {
    let root = std::env::temp_dir().join(format!("twinbots-bc-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let demos = cartpole_demos(&root, 8);
    let mut env = ClassicCartPole::new(4);

    // Untrained, the policy lets the pole fall; cloned for 400 gradient steps, it holds it.
    let mut bc = cartpole_bc(&demos, 0);
    let before = evaluate_policy("balance", &bc, &mut env, 8, 7).unwrap().mean_score;
    let end = bc.learn(&mut env, 400 * 256, &mut CallbackList::new()).unwrap();
    assert_eq!(end, TrainingEnd::BudgetSpent { timesteps: 400 * 256 });
    assert_eq!((bc.gradient_steps, bc.state.updates), (400, 4));
    let after = evaluate_policy("balance", &bc, &mut env, 8, 7).unwrap().mean_score;
    assert!(before < 200.0 && after > 450.0, "mean score {before} untrained, {after} cloned");
    assert!(bc.last_loss < 0.2, "cross-entropy {}", bc.last_loss);
    // The observation statistics are the dataset's: 4,000 frames.
    assert_eq!(bc.state.obs_rms.as_ref().map(|r| r.count), Some(4000.0));

    // 200 steps, saved, loaded and 200 more: the uninterrupted run's weights bit for bit.
    let mut first = cartpole_bc(&demos, 0);
    first.learn(&mut env, 200 * 256, &mut CallbackList::new()).unwrap();
    first.save(root.join("half")).unwrap();
    let mut resumed = Bc::load(root.join("half")).unwrap();
    resumed.learn(&mut env, 200 * 256, &mut CallbackList::new()).unwrap();
    let values = |m: &Bc| m.policy_net().unwrap().layers;
    assert_eq!(values(&resumed), values(&bc), "the resumed run differs from the uninterrupted one");
    // What it exports acts as it does: the arg max of its logits.
    assert_eq!(bc.policy_net().unwrap().head, PolicyHead::ArgMax);

    // A dataset that does not fit the robot is refused, naming itself and the feature.
    let pendulum = crate::classic::ClassicPendulum::new(1);
    let config = BcConfig { demos: demos.display().to_string(), ..BcConfig::default() };
    let mut wrong = Bc::new(config, pendulum.observation_space().clone(), pendulum.action_space().clone(), 0).unwrap();
    let err = wrong.learn(&mut env, 256, &mut CallbackList::new()).unwrap_err().to_string();
    assert!(
        err.contains(&demos.display().to_string()) && err.contains("has 4 values a frame, the robot observes 3"),
        "{err}"
    );
    std::fs::remove_dir_all(&root).unwrap();
}
