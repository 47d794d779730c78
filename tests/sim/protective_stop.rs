//! The UR5e's protective stop (issue 18): a wrist whipped round past its speed limit by the
//! shoulder and elbow reversing at full torque stops the arm. The episode ends the step the
//! stop trips, as a failure counted in `protective_stops`, under design patterns 1 and 3;
//! under pattern 3 the robot then brakes to rest, held, takes no commands, and homes once the
//! stop is unlocked. The classical controller's motion never stops it.

use bevy::prelude::*;
use twinbots_api::{DesignPattern, EpisodeSummary, VecEnv};
use twinbots_link::robot::{Controller, OnBoardPolicy, Phase, RobotRunState};
use twinbots_sim::{Motor, MotorCommand};
use twinbots_task::{AppVecEnv, Episode};
use ur5e::CellState;
use ur5e::safety::{EFFORT_MARGIN, MAX_BRAKING_STEPS, REST_SPEED, SPEED_MARGIN, StopCause};

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

/// What an episode a stop ended shows: a failure, one stop, penalised (its pose cost and the
/// forfeited arrival bonus).
fn assert_ended_by_a_stop(episode: &EpisodeSummary) {
    assert_eq!(episode.success, Some(false), "a protective stop is a failure: {episode:?}");
    assert_eq!(figure(episode, "protective_stops"), 1.0);
    assert!(episode.rewards["protective_stop"] < 0.0, "the stop is penalised: {:?}", episode.rewards);
    // However close to the target it trips, a stop forfeits the arrival bonus.
    assert_eq!(episode.rewards["stop_forfeit"], -ur5e::reach::ARRIVAL_BONUS, "{:?}", episode.rewards);
}

/// A wrist, run past the stop's margin.
fn assert_wrist_overspeed(cause: StopCause) {
    match cause {
        StopCause::Speed { joint, ratio } => {
            assert!(joint >= 3, "a 28 N·m wrist is what gets overpowered, not joint {joint}");
            assert!(ratio > 1.0 + SPEED_MARGIN, "stopped at {ratio}× the limit");
        }
        other => panic!("no speed stop: {other:?}"),
    }
}

#[test]
fn a_wrist_whipped_round_makes_a_protective_stop_that_ends_the_episode_at_once() {
    let mut env = AppVecEnv::new(ur5e::headless_app_with(1, 3, DesignPattern::Supervised));
    let arena = env.arenas()[0];
    let mut obs = env.reset(Some(3)).unwrap();
    for step_index in 0..ur5e::reach::EPISODE_STEPS {
        let step = env.step(&reversing(&obs)).unwrap();
        let state = env.app().world().get::<CellState>(arena).unwrap();
        if let Some(episode) = &step.episodes[0] {
            assert!(step.terminated[0], "ended by the stop, not the time limit");
            assert_ended_by_a_stop(episode);
            assert!(state.safety.stop.is_none(), "the reset unlocks the stop");
            eprintln!("stopped at step {step_index}: {:?}", episode.rewards);
            return;
        }
        // The episode ends the step a stop trips: one that goes on is never stopped.
        assert!(state.safety.stop.is_none(), "stopped at step {step_index}, but the episode goes on");
        obs = step.obs;
    }
    panic!("no protective stop in a whole episode of reversals");
}

#[test]
fn under_pattern_3_a_protective_stop_ends_the_episode_and_the_arm_brakes_to_rest_then_homes() {
    let mut app = ur5e::headless_app_with(1, 3, DesignPattern::Server);
    let policy = OnBoardPolicy::new(|obs: &[f32]| Ok(reversing(obs)));
    app.insert_resource(policy);
    app.finish();
    app.cleanup();
    app.update();
    // Control steps braked since the episode ended, and the speeds last read while stopped.
    let (mut stops, mut braking, mut last_speeds) = (0, None::<u32>, [0.0f32; 6]);
    for _ in 0..2000 {
        app.update();
        let world = app.world_mut();
        assert!(world.resource::<RobotRunState>().stop.is_none(), "{:?}", world.resource::<RobotRunState>().stop);
        let (controller, state, episode) = world.query::<(&Controller, &CellState, &Episode)>().single(world).unwrap();
        let (phase, stop, speeds) = (controller.phase(), state.safety.stop, state.arm.qd);
        if let Some(summary) = episode.finished() {
            assert_ended_by_a_stop(summary);
            assert_wrist_overspeed(stop.expect("the episode ends the step the stop trips, still stopped"));
            assert_eq!(phase, Phase::Homing, "after the stop the robot brakes and homes");
            stops += 1;
            braking = Some(0);
        } else if let Some(steps) = &mut braking {
            if stop.is_some() {
                // Braking: every joint is held, whatever the policy would say.
                *steps += 1;
                last_speeds = speeds;
                assert!(*steps <= MAX_BRAKING_STEPS, "braked for {steps} steps");
                let parts = world.query::<&ur5e::cell::CellParts>().single(world).unwrap().clone();
                for &joint in &parts.joints {
                    assert_eq!(
                        world.get::<Motor>(joint).unwrap().command,
                        MotorCommand::Velocity(0.0),
                        "a stopped joint holds"
                    );
                }
            } else {
                // Unlocked (and homing) only once the arm had come to rest.
                let at_rest = last_speeds.iter().all(|v| v.abs() < REST_SPEED);
                assert!(
                    *steps >= 1 && (at_rest || *steps == MAX_BRAKING_STEPS),
                    "unlocked after {steps} steps at {last_speeds:?}"
                );
                eprintln!("braked to rest in {steps} control steps");
                braking = None;
                if stops == 2 {
                    // Stopped, braked, unlocked and homed, twice: the cycle goes on.
                    return;
                }
            }
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

/// The torque branch: drives made stronger than their rating (a motor randomised to 1.5× its
/// strength, as `motor_strength` can) start the arm towards the table at full torque, and the
/// torque feedback beyond 1.1× the rating stops it at once — under pattern 3, where the robot's
/// own controller judges. (At strength 1.0 the same motion ends no episode by torque.)
#[test]
fn a_drive_pushing_beyond_its_rated_torque_makes_a_protective_stop() {
    let mut app = ur5e::headless_app_with(1, 5, DesignPattern::Server);
    // Shoulder lift and elbow at full speed towards the table, the wrists still.
    app.insert_resource(OnBoardPolicy::new(|_: &[f32]| Ok(vec![0.0, DOWN, DOWN, 0.0, 0.0])));
    app.finish();
    app.cleanup();
    app.update();
    let world = app.world_mut();
    let parts = world.query::<&ur5e::cell::CellParts>().single(world).unwrap().clone();
    for &joint in &parts.joints {
        world.get_mut::<Motor>(joint).unwrap().strength = 1.5;
    }
    for step in 0..500 {
        app.update();
        let world = app.world_mut();
        let (state, episode) = world.query::<(&CellState, &Episode)>().single(world).unwrap();
        if let Some(summary) = episode.finished() {
            assert_ended_by_a_stop(summary);
            match state.safety.stop.expect("still stopped the step the episode ends") {
                StopCause::Effort { joint, ratio } => {
                    assert!(ratio > 1.0 + EFFORT_MARGIN && ratio <= 1.5 + 1e-3, "joint {joint} at {ratio}× its rating");
                    eprintln!("joint {joint} at {ratio:.2}× its rating stopped the arm at step {step}");
                    return;
                }
                other => panic!("stopped by {other:?}, not by torque"),
            }
        }
    }
    panic!("no protective stop in 500 steps of pushing into the table");
}

/// The sign of a reach action that turns the shoulder lift and elbow towards the table.
const DOWN: f32 = 1.0;
