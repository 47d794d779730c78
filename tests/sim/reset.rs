//! The Supervisor resets an arena to exactly its initial state, and arenas are independent.

use twinbots_api::VecEnv;
use twinbots_sim::{Arena, JointState, Motor, MotorCommand};
use twinbots_task::AppVecEnv;

use crate::common::with_supervisor;

fn hash(env: &AppVecEnv, i: usize) -> u64 {
    env.app().world().get::<Arena>(env.arenas()[i]).unwrap().state_hash()
}

#[test]
fn reset_restores_the_initial_state_exactly() {
    let mut env = AppVecEnv::new(cartpole::headless_app(1, 3));
    let arena = env.arenas()[0];
    let initial = hash(&env, 0);
    let parts = *env.app().world().get::<cartpole::CartPoleParts>(arena).unwrap();
    let initial_pole = *env.app().world().get::<JointState>(parts.pole_joint).unwrap();
    env.reset(Some(3)).unwrap();
    for i in 0..40 {
        env.step(&[(i % 3 == 0) as u8 as f32]).unwrap();
    }
    assert_ne!(hash(&env, 0), initial, "the arena moved");
    assert!(with_supervisor(env.app_mut(), |s| s.reset_arena(arena)));
    assert_eq!(hash(&env, 0), initial, "poses and velocities restored bit for bit");
    let world = env.app().world();
    assert_eq!(*world.get::<JointState>(parts.pole_joint).unwrap(), initial_pole);
    assert_eq!(world.get::<Motor>(parts.wheels[0]).unwrap().command, MotorCommand::Off);
}

#[test]
fn acting_in_one_arena_leaves_the_others_untouched() {
    let run = |arena0_action: f32| {
        let mut env = AppVecEnv::new(cartpole::headless_app(2, 11));
        env.reset(Some(11)).unwrap();
        for _ in 0..100 {
            env.step(&[arena0_action, 0.0]).unwrap();
        }
        (hash(&env, 0), hash(&env, 1))
    };
    let (a0, a1) = run(1.0);
    let (b0, b1) = run(0.0);
    assert_ne!(a0, b0, "arena 0 followed different actions");
    assert_eq!(a1, b1, "arena 1 did not notice");
}
