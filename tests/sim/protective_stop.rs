//! The UR5e's protective stop (issue 18): a wrist whipped round past its speed limit by the
//! shoulder and elbow reversing at full torque stops the arm. It brakes to rest, takes no more
//! commands, and the episode ends as a failure counted in `protective_stops`, under design
//! patterns 1 and 3. The classical controller's motion never stops it.

use bevy::prelude::*;
use twinbots_rl::{AppVecEnv, DesignPattern, Episode, EpisodeSummary, VecEnv};
use twinbots_server::robot::{Controller, OnBoardPolicy, Phase, RobotRunState};
use twinbots_sim::{Motor, MotorCommand};
use ur5e::CellState;
use ur5e::safety::{REST_SPEED, SPEED_MARGIN, StopCause};

/// Where the reach observation holds the joints' speeds.
fn joint_speeds_at() -> usize {
    let names = ur5e::task_spec().observation_names;
    names.iter().position(|n| n == "joint_velocities[0]").expect("the reach observes joint speeds")
}

/// The shoulder lift and the elbow driven at full speed against the way the shoulder turns,
/// wrist 1 the other way: all three reverse every step, at full torque, and wrist 1, 28 N·m,
/// is whipped round by the other two (past 1.5× its limit within a few steps).
fn reversing(obs: &[f32]) -> Vec<f32> {
    let shoulder = obs[joint_speeds_at() + 1];
    let a = if shoulder > 0.0 { -1.0 } else { 1.0 };
    vec![0.0, a, a, -a, 0.0]
}

fn figure(ep: &EpisodeSummary, name: &str) -> f32 {
    *ep.metrics.get(name).unwrap_or_else(|| panic!("episode reports no {name}: {:?}", ep.metrics))
}

/// What a finished stop showed: the cause, and the episode.
fn assert_stopped_at_rest(cause: Option<StopCause>, episode: &EpisodeSummary, final_speeds: &[f32]) {
    match cause {
        Some(StopCause::Speed { joint, ratio }) => {
            assert!(joint >= 3, "a 28 N·m wrist is what gets overpowered, not joint {joint}");
            assert!(ratio > 1.0 + SPEED_MARGIN, "stopped at {ratio}× the limit");
        }
        other => panic!("no speed stop: {other:?}"),
    }
    assert_eq!(episode.success, Some(false), "a protective stop is a failure: {episode:?}");
    assert_eq!(figure(episode, "protective_stops"), 1.0);
    assert!(final_speeds.iter().all(|v| v.abs() < REST_SPEED), "the arm is not at rest at the episode's end: {final_speeds:?}");
}

#[test]
fn a_wrist_whipped_round_makes_a_protective_stop_and_the_arm_brakes_to_rest() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(1, 3, DesignPattern::Supervised));
    let arena = env.arenas()[0];
    let speeds = joint_speeds_at()..joint_speeds_at() + 6;
    let mut obs = env.reset(Some(3)).unwrap();
    let (mut cause, mut braking) = (None, 0);
    for _ in 0..ur5e::reach::EPISODE_STEPS {
        let step = env.step(&reversing(&obs)).unwrap();
        if let Some(episode) = &step.episodes[0] {
            assert!(step.terminated[0], "ended by the stop, not the time limit");
            let last = step.final_obs[0].as_ref().expect("the last observation is kept");
            assert_stopped_at_rest(cause, episode, &last[speeds.clone()]);
            assert!(episode.rewards["protective_stop"] < 0.0, "the stop is penalised: {:?}", episode.rewards);
            assert!((1..=ur5e::safety::MAX_BRAKING_STEPS).contains(&braking), "braked for {braking} steps");
            eprintln!("{cause:?}, braked to rest in {braking} control steps");
            return;
        }
        let world = env.app().world();
        let state = world.get::<CellState>(arena).unwrap();
        if let Some(stop) = state.safety.stop {
            // Stopped: the reversing commands are ignored and every joint is held.
            cause.get_or_insert(stop);
            braking += 1;
            let parts = world.get::<ur5e::cell::CellParts>(arena).unwrap();
            for &joint in &parts.joints {
                assert_eq!(world.get::<Motor>(joint).unwrap().command, MotorCommand::Velocity(0.0), "a stopped joint holds");
            }
        }
        obs = step.obs;
    }
    panic!("no protective stop in a whole episode of reversals (cause {cause:?})");
}

#[test]
fn under_pattern_3_a_protective_stop_ends_the_episode_and_the_arm_homes_after_it() {
    let mut app = ur5e::headless_app_with(1, 3, DesignPattern::Server);
    let policy = OnBoardPolicy::new(|obs: &[f32]| Ok(reversing(obs)));
    app.insert_resource(policy);
    app.finish();
    app.cleanup();
    app.update();
    let speeds = joint_speeds_at()..joint_speeds_at() + 6;
    let (mut cause, mut stops) = (None, 0);
    for _ in 0..2000 {
        app.update();
        let world = app.world_mut();
        assert!(world.resource::<RobotRunState>().stop.is_none(), "{:?}", world.resource::<RobotRunState>().stop);
        let (controller, state, episode) = world.query::<(&Controller, &CellState, &Episode)>().single(world).unwrap();
        if let Some(stop) = state.safety.stop {
            cause.get_or_insert(stop);
        }
        if let Some(summary) = &episode.finished {
            let last = episode.final_observation.as_ref().expect("the last observation is kept");
            assert_stopped_at_rest(cause.take(), summary, &last[speeds.clone()]);
            assert_eq!(controller.phase(), Phase::Homing, "after the stop the robot homes");
            stops += 1;
        }
        if stops == 2 {
            // Unlocked, homed and stopped again: the cycle goes on.
            return;
        }
    }
    panic!("{stops} protective stops in 2000 steps");
}

#[test]
fn the_classical_controller_never_makes_a_protective_stop() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(4, 21, DesignPattern::Supervised));
    let dim = env.observation_space().dim();
    let mut obs = env.reset(Some(21)).unwrap();
    let mut episodes = Vec::new();
    while episodes.len() < 40 {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(ur5e::controller::act).collect();
        let step = env.step(&actions).unwrap();
        episodes.extend(step.episodes.into_iter().flatten());
        obs = step.obs;
    }
    for ep in &episodes {
        assert_eq!(figure(ep, "protective_stops"), 0.0, "{ep:?}");
        assert_eq!(ep.success, Some(true), "{ep:?}");
    }
}
