//! The twins' physics timing is chosen by measurement: a trajectory at a twin's training
//! settings (physics step, substeps, solver iterations) stays within a bound of the same
//! trajectory at a fine-step reference (1 ms steps, 16 solver iterations), and a coarser
//! timing does not (so the bound can fail). The UR5e's timing is bounded by its forward-
//! kinematics tests (tests/sim/ur5e_cell.rs).

use rand::{Rng, SeedableRng};
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_sim::SimSettings;
use twinbots_task::AppVecEnv;
use twinbots_task::robot::{AppRequest, headless_app};

/// Which twin a rollout runs.
#[derive(Clone, Copy)]
enum Twin {
    CartPole,
    Pioneer,
}

/// Observations [x, v, angle, rate] along an open-loop action sequence from the start the seed
/// draws, until the episode ends.
fn rollout(twin: Twin, settings: SimSettings, seed: u64, actions: &[f32]) -> Vec<[f32; 4]> {
    let request = AppRequest { task: "balance", arenas: 1, seed, pattern: DesignPattern::Supervised };
    let app = match twin {
        Twin::CartPole => headless_app(settings, &request, cartpole::CartPolePlugin::default()),
        Twin::Pioneer => headless_app(settings, &request, pioneer3at::Pioneer3atPlugin),
    };
    let mut env = AppVecEnv::new(app);
    env.reset(Some(seed)).unwrap();
    let mut out = Vec::new();
    for &a in actions {
        let step = env.step(&[a]).unwrap();
        if step.terminated[0] || step.truncated[0] {
            break; // the next observation is a new episode's
        }
        out.push([step.obs[0], step.obs[1], step.obs[2], step.obs[3]]);
    }
    out
}

/// A fine-step version of `settings`: the same control step in 1 ms physics steps.
fn reference(settings: SimSettings) -> SimSettings {
    let control = settings.control_dt();
    let substeps = (control / 0.001).round() as u32;
    SimSettings { dt: control / substeps as f32, substeps, solver_iterations: 16, ..settings }
}

/// Largest deviation of each observation over `seeds` rollouts of `steps` random actions.
fn max_error(twin: Twin, settings: SimSettings, seeds: u64, steps: usize) -> [f32; 4] {
    let mut worst = [0.0f32; 4];
    for seed in 0..seeds {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(100 + seed);
        let actions: Vec<f32> = (0..steps)
            .map(|_| match twin {
                Twin::CartPole => rng.random_range(0..2) as f32,
                Twin::Pioneer => rng.random_range(-pioneer3at::MAX_WHEEL_SPEED..pioneer3at::MAX_WHEEL_SPEED),
            })
            .collect();
        let coarse = rollout(twin, settings, seed, &actions);
        let fine = rollout(twin, reference(settings), seed, &actions);
        for (c, f) in coarse.iter().zip(&fine) {
            for k in 0..4 {
                worst[k] = worst[k].max((c[k] - f[k]).abs());
            }
        }
    }
    worst
}

/// Over 20 control steps (0.64 s) of random actions, the cart stays within 1 cm (2.5 % of its
/// ±0.4 m track) and the pole within 0.015 rad (6 % of its 15° limit) of the reference.
const CARTPOLE_BOUND: [f32; 4] = [0.01, f32::INFINITY, 0.015, f32::INFINITY];

#[test]
fn the_cartpole_training_timing_tracks_a_fine_step_reference() {
    let error = max_error(Twin::CartPole, cartpole::sim_settings(), 8, 20);
    assert!(
        error[0] < CARTPOLE_BOUND[0] && error[2] < CARTPOLE_BOUND[2],
        "error {error:?} vs bound {CARTPOLE_BOUND:?}"
    );
    // The bound separates: one 32 ms physics step of 4 solver iterations does not keep it.
    let coarse = SimSettings { dt: 0.032, substeps: 1, solver_iterations: 4, ..cartpole::sim_settings() };
    let error = max_error(Twin::CartPole, coarse, 8, 20);
    assert!(error[0] > CARTPOLE_BOUND[0] || error[2] > CARTPOLE_BOUND[2], "error {error:?}");
}

/// Over 40 control steps (2.56 s) of random wheel speeds, the base within 2 cm and the pendulum
/// within 0.06 rad of the reference. Every cheaper timing measured did worse or no better
/// (docs/design/simulation.md, "Physics timing"), so the Pioneer keeps its 8 × 8 ms steps of 4 iterations.
const PIONEER_BOUND: [f32; 4] = [0.02, f32::INFINITY, 0.06, f32::INFINITY];

#[test]
fn the_pioneer_training_timing_tracks_a_fine_step_reference() {
    let error = max_error(Twin::Pioneer, pioneer3at::sim_settings(), 6, 40);
    assert!(error[0] < PIONEER_BOUND[0] && error[2] < PIONEER_BOUND[2], "error {error:?} vs bound {PIONEER_BOUND:?}");
    let coarse = SimSettings { dt: 0.032, substeps: 2, solver_iterations: 8, ..pioneer3at::sim_settings() };
    let error = max_error(Twin::Pioneer, coarse, 6, 40);
    assert!(error[0] > PIONEER_BOUND[0] || error[2] > PIONEER_BOUND[2], "error {error:?}");
}
