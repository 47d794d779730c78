//! The paper's design patterns on the cart-pole.

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_sim::{Motor, MotorCommand, PositionSensor};
use twinbots_task::AppVecEnv;

fn radio_env() -> AppVecEnv {
    let mut env = AppVecEnv::new(cartpole::headless_app_with(1, 6, DesignPattern::Radio));
    env.reset(Some(6)).unwrap();
    env
}

#[test]
fn pattern_2_actions_reach_the_slave_one_step_late() {
    let mut env = radio_env();
    let parts = *env.app().world().get::<cartpole::CartPoleParts>(env.arenas()[0]).unwrap();
    let wheel = |env: &AppVecEnv| env.app().world().get::<Motor>(parts.wheels[0]).unwrap().command;
    env.step(&[1.0]).unwrap();
    assert_eq!(wheel(&env), MotorCommand::Off, "the first action is still in the air");
    env.step(&[0.0]).unwrap();
    assert_eq!(wheel(&env), MotorCommand::Velocity(cartpole::WHEEL_SPEED), "step 1's action, one step late");
    env.step(&[0.0]).unwrap();
    assert_eq!(wheel(&env), MotorCommand::Velocity(-cartpole::WHEEL_SPEED));
}

#[test]
fn pattern_2_observed_pole_angle_is_the_slaves_reading_from_the_step_before() {
    let mut env = radio_env();
    let parts = *env.app().world().get::<cartpole::CartPoleParts>(env.arenas()[0]).unwrap();
    let sensor = |env: &AppVecEnv| env.app().world().get::<PositionSensor>(parts.pole_joint).unwrap().value;
    // Step 0 after a reset: nothing has arrived yet, so the supervisor reads the angle itself.
    env.step(&[0.0]).unwrap();
    let mut previous = sensor(&env);
    for i in 1..20 {
        let obs = env.step(&[(i % 2) as f32]).unwrap().obs;
        assert_eq!(obs[2], previous, "step {i}: the angle travelled one step by radio");
        assert_ne!(obs[2], sensor(&env), "step {i}: not the current reading");
        previous = sensor(&env);
    }
}
