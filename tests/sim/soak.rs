//! Random-action soaks of every built-in robot (issue 15.6, 18.4): under uniformly random
//! actions, every joint stays within its URDF `<limit>` (position range, and for a motor its
//! velocity limit, checked every physics step), and no body's pose or velocity becomes NaN or
//! explodes. The UR5e's wrists can be overpowered (random actions reverse the shoulder and
//! elbow at full torque every 40 ms, which whips a 28 N·m wrist round); its controller then
//! makes a protective stop (`ur5e::safety`), and the soak checks that outside a stop no joint
//! ran past the stop's thresholds, and that every stop ended its episode the step it tripped.
//!
//! The suite runs a short soak per robot. The long one (1 M control steps a robot) is ignored
//! by default:
//!
//! ```text
//! TWINBOTS_SOAK_STEPS=1000000 cargo test --release --test sim soak_long -- --ignored --nocapture
//! ```

use bevy::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_run::registry;
use twinbots_sim::{Arena, InArena, Joint, JointState, Motor, PhysicsSubstep, SimSettings, SubstepSet};
use twinbots_task::AppVecEnv;
use ur5e::safety::{OVERSPEED_TIME, PEAK_SPEED_MARGIN, SPEED_MARGIN};

/// How far (rad or m) a joint may be measured past a position stop: contacts and the solver
/// give way a little before the stop holds.
pub const POSITION_TOLERANCE: f32 = 0.02;
/// No body of a cell goes this far (m) from the origin, or this fast (m/s, rad/s).
const BODY_BOUND: f32 = 100.0;

/// The worst a soak saw.
#[derive(Clone, Debug, Default)]
pub struct SoakReport {
    pub robot: String,
    /// Control steps, summed over arenas.
    pub arena_steps: u64,
    pub episodes: u64,
    /// The largest overrun of a position stop (rad or m), and the joint.
    pub worst_position_overrun: (f32, String),
    /// Outside a protective stop, every physics step: the fastest joint (|velocity| / velocity
    /// limit), and the longest time (s) a joint ran over its limit by more than the stop's
    /// margin, each with the joint. A robot without a safety system is never in a stop: its
    /// drives must keep within the same bounds by themselves.
    pub peak_speed_ratio_running: (f32, String),
    pub longest_overspeed: (f32, String),
    /// The fastest joint at any physics step, during stops too, and the joint.
    pub peak_speed_ratio: (f32, String),
    /// Episodes that a protective stop ended, and stops that did not end their episode the
    /// control step they tripped (an arena still stopped after a step that ended nothing).
    pub protective_stops: u64,
    pub stops_not_ending_episode: u64,
    /// The fastest body (m/s or rad/s) and farthest body (m from the origin).
    pub peak_body_speed: f32,
    pub peak_body_distance: f32,
    /// Non-finite readings (joint states, body poses and velocities).
    pub non_finite: u64,
    pub seconds: f64,
}

impl SoakReport {
    /// Every violation, one line each.
    pub fn violations(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.non_finite > 0 {
            out.push(format!("{} non-finite readings", self.non_finite));
        }
        if self.worst_position_overrun.0 > POSITION_TOLERANCE {
            out.push(format!(
                "{} went {:.4} past its stop",
                self.worst_position_overrun.1, self.worst_position_overrun.0
            ));
        }
        if self.peak_speed_ratio_running.0 > 1.0 + PEAK_SPEED_MARGIN {
            let (ratio, joint) = &self.peak_speed_ratio_running;
            out.push(format!("{joint} ran at {ratio:.2}× its velocity limit, not in a protective stop"));
        }
        // Half a physics step's slack, as the safety system allows for rounding.
        if self.longest_overspeed.0 > OVERSPEED_TIME - 0.002 {
            let (time, joint) = &self.longest_overspeed;
            out.push(format!(
                "{joint} ran over {:.0} % of its velocity limit for {time:.3} s, not in a protective stop",
                SPEED_MARGIN * 100.0
            ));
        }
        if self.stops_not_ending_episode > 0 {
            out.push(format!("{} protective stops did not end their episode at once", self.stops_not_ending_episode));
        }
        if self.peak_body_speed > BODY_BOUND || self.peak_body_distance > BODY_BOUND {
            out.push(format!("a body exploded: {} m/s, {} m", self.peak_body_speed, self.peak_body_distance));
        }
        out
    }
}

fn keep_max(slot: &mut (f32, String), value: f32, name: &str) {
    if value > slot.0 || slot.1.is_empty() {
        *slot = (value.max(slot.0), name.to_string());
    }
}

/// Checks every joint's position and every body of the app's world into `report` (after a
/// control step).
fn inspect(world: &mut World, report: &mut SoakReport) {
    let mut joints = world.query::<(&Joint, &JointState)>();
    for (joint, state) in joints.iter(world) {
        if !(state.position.is_finite() && state.velocity.is_finite() && state.effort.is_finite()) {
            report.non_finite += 1;
            continue;
        }
        if let Some([lo, hi]) = joint.limits {
            let over = (lo - state.position).max(state.position - hi).max(0.0);
            keep_max(&mut report.worst_position_overrun, over, &joint.name);
        }
    }
    let privilege = world.resource::<twinbots_sim::SupervisorAccess>();
    let mut arenas = world.try_query::<&Arena>().expect("arenas are registered");
    for arena in arenas.iter(world) {
        for (_, body) in arena.physics(privilege).bodies.iter() {
            let p = body.translation();
            let (v, w) = (body.linvel(), body.angvel());
            if !(p.is_finite() && v.is_finite() && w.is_finite()) {
                report.non_finite += 1;
                continue;
            }
            report.peak_body_distance = report.peak_body_distance.max(p.length());
            report.peak_body_speed = report.peak_body_speed.max(v.length()).max(w.length());
        }
    }
}

/// Motor speeds of every physics step, taken after the safety system's check.
#[derive(Resource, Default)]
struct SpeedLog {
    peak_running: (f32, String),
    longest_overspeed: (f32, String),
    peak: (f32, String),
    /// Per joint entity: how long it has run over the margin outside a stop.
    overspeed_for: std::collections::HashMap<Entity, f32>,
}

fn log_speeds(
    settings: Res<SimSettings>,
    mut log: ResMut<SpeedLog>,
    joints: Query<(Entity, &Joint, &JointState, &Motor, &InArena)>,
    cells: Query<&ur5e::CellState>,
) {
    for (entity, joint, state, motor, in_arena) in &joints {
        let ratio = state.velocity.abs() / motor.max_velocity;
        keep_max(&mut log.peak, ratio, &joint.name);
        if cells.get(in_arena.0).is_ok_and(|cell| cell.safety.stopped()) {
            log.overspeed_for.remove(&entity);
            continue;
        }
        keep_max(&mut log.peak_running, ratio, &joint.name);
        let over = log.overspeed_for.entry(entity).or_default();
        *over = if ratio > 1.0 + SPEED_MARGIN { *over + settings.dt } else { 0.0 };
        let over = *over;
        keep_max(&mut log.longest_overspeed, over, &joint.name);
    }
}

/// Steps `robot`'s main task (pattern 1) with `arenas` arenas under uniformly random actions
/// drawn from `seed` for `steps` control steps, checking every physics step (speeds) and after
/// every control step (positions, bodies, episodes that ended in a protective stop).
pub fn soak(robot: &str, arenas: usize, steps: u64, seed: u64) -> SoakReport {
    let entry = registry::find(robot).expect("a built-in robot");
    let mut app = entry.app(None, arenas, seed, DesignPattern::Supervised).expect("pattern 1 is supported");
    app.init_resource::<SpeedLog>().add_systems(PhysicsSubstep, log_speeds.after(SubstepSet::Record));
    let mut env = AppVecEnv::new(app);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut report = SoakReport { robot: robot.to_string(), ..default() };
    let start = std::time::Instant::now();
    env.reset(Some(seed)).expect("reset");
    inspect(env.app_mut().world_mut(), &mut report);
    let space = env.action_space().clone();
    for _ in 0..steps {
        let actions: Vec<f32> = (0..arenas).flat_map(|_| space.sample(&mut rng)).collect();
        let step = env.step(&actions).expect("the app steps");
        for (i, episode) in step.episodes.iter().enumerate() {
            let Some(episode) = episode else { continue };
            report.episodes += 1;
            report.protective_stops +=
                u64::from(episode.metrics.get("protective_stops").is_some_and(|&n| n > 0.0) && step.terminated[i]);
        }
        // A stop ends its episode the step it trips, and the reset unlocks it: an arena whose
        // episode goes on is never stopped.
        for (i, &arena) in env.arenas().iter().enumerate() {
            let stopped = env.app().world().get::<ur5e::CellState>(arena).is_some_and(|c| c.safety.stopped());
            report.stops_not_ending_episode += u64::from(stopped && step.episodes[i].is_none());
        }
        report.arena_steps += arenas as u64;
        inspect(env.app_mut().world_mut(), &mut report);
    }
    let log = env.app().world().resource::<SpeedLog>();
    (report.peak_speed_ratio_running, report.longest_overspeed, report.peak_speed_ratio) =
        (log.peak_running.clone(), log.longest_overspeed.clone(), log.peak.clone());
    report.seconds = start.elapsed().as_secs_f64();
    report
}

fn assert_sound(report: &SoakReport) {
    eprintln!("{report:?}");
    let violations = report.violations();
    assert!(violations.is_empty(), "{}: {}", report.robot, violations.join("; "));
}

#[test]
fn the_ur5e_stays_within_its_joint_limits_under_random_actions() {
    let report = soak("ur5e", 4, 1500, 7);
    assert_sound(&report);
    assert!(report.protective_stops > 0, "random actions overpower a wrist: the soak sees protective stops");
}

#[test]
fn the_cartpole_stays_sound_under_random_actions() {
    assert_sound(&soak("cartpole", 4, 1500, 7));
}

#[test]
fn the_pioneer_stays_sound_under_random_actions() {
    assert_sound(&soak("pioneer3at", 4, 1500, 7));
}

/// The long soak: `TWINBOTS_SOAK_STEPS` control steps (default 1 M, on one arena) for
/// `TWINBOTS_SOAK_ROBOT` (default: every robot).
#[test]
#[ignore = "long: 1 M control steps a robot (see the module's doc)"]
fn soak_long() {
    let steps =
        std::env::var("TWINBOTS_SOAK_STEPS").map_or(1_000_000, |s| s.parse().expect("TWINBOTS_SOAK_STEPS is a count"));
    let robots = std::env::var("TWINBOTS_SOAK_ROBOT")
        .map_or(vec!["cartpole".to_string(), "pioneer3at".into(), "ur5e".into()], |r| vec![r]);
    for robot in robots {
        assert_sound(&soak(&robot, 1, steps, 1));
    }
}
