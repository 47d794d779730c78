//! The twins' physics timing is chosen by measurement: a trajectory at a twin's training
//! settings (physics step, substeps, solver iterations) stays within a bound of the same
//! trajectory at a fine-step reference (1 ms steps, 16 solver iterations).

use rand::{Rng, SeedableRng};
use twinbots_rl::robot::{AppRequest, headless_app};
use twinbots_rl::{AppVecEnv, DesignPattern, VecEnv};
use twinbots_sim::SimSettings;

/// Cart-pole observations [x, v, angle, rate] along an open-loop action sequence from the start
/// the seed draws.
fn cartpole_rollout(settings: SimSettings, seed: u64, actions: &[f32]) -> Vec<[f32; 4]> {
    let request = AppRequest { task: "balance", arenas: 1, seed, pattern: DesignPattern::Supervised };
    let mut env = AppVecEnv::new(headless_app(settings, &request, cartpole::CartPolePlugin::default()));
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
fn cartpole_error(settings: SimSettings, seeds: u64, steps: usize) -> [f32; 4] {
    let mut worst = [0.0f32; 4];
    for seed in 0..seeds {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(100 + seed);
        let actions: Vec<f32> = (0..steps).map(|_| rng.random_range(0..2) as f32).collect();
        let coarse = cartpole_rollout(settings, seed, &actions);
        let fine = cartpole_rollout(reference(settings), seed, &actions);
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
    let error = cartpole_error(cartpole::sim_settings(), 8, 20);
    assert!(error[0] < CARTPOLE_BOUND[0] && error[2] < CARTPOLE_BOUND[2], "error {error:?} vs bound {CARTPOLE_BOUND:?}");
    // The bound separates: one 32 ms physics step of 4 solver iterations does not keep it.
    let coarse = SimSettings { dt: 0.032, substeps: 1, solver_iterations: 4, ..cartpole::sim_settings() };
    let error = cartpole_error(coarse, 8, 20);
    assert!(error[0] > CARTPOLE_BOUND[0] || error[2] > CARTPOLE_BOUND[2], "error {error:?}");
}
