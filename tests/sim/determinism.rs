//! Same seed and actions, same trajectory, bit for bit; another seed, another trajectory.

use rand::{Rng, SeedableRng};
use twinbots_rl::{AppVecEnv, VecEnv};
use twinbots_sim::Arena;

fn run(seed: u64, steps: usize) -> Vec<u64> {
    let arenas = 3;
    let mut env = AppVecEnv::new(cartpole::headless_app(arenas, seed));
    env.reset(Some(seed)).unwrap();
    let mut actions = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    for _ in 0..steps {
        let a: Vec<f32> = (0..arenas).map(|_| actions.random_range(0..2) as f32).collect();
        env.step(&a).unwrap();
    }
    env.arenas()
        .iter()
        .map(|&e| env.app().world().get::<Arena>(e).unwrap().state_hash())
        .collect()
}

#[test]
fn same_seed_gives_identical_state_after_1000_steps() {
    let a = run(7, 1000);
    assert_eq!(a, run(7, 1000));
    assert_ne!(a, run(8, 1000), "a different seed starts the poles differently");
}
