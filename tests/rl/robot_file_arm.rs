//! An arm from a robot file alone (a URDF and a few keys, no Rust): its twin follows the
//! controller's own kinematics, a resolved-rate controller on the reach task's observation
//! arrives, a joint driven into its stop trips the protective stop, and the goal interface
//! recomputes the task's own reward.

use std::path::{Path, PathBuf};

use bevy::math::Vec2;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_arm::reach::{ReachState, STOP_TERM, resolved_rate};
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sim::{InArena, Link, physics_in};
use twinbots_task::AppVecEnv;

/// A three-joint arm of boxes: a base turning about z, a shoulder and an elbow about y, a tool
/// link 0.3 m past the elbow.
const URDF: &str = r#"<robot name="arm3">
  <link name="base"><inertial><origin xyz="0 0 0.05"/><mass value="5"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.08" length="0.1"/></geometry></collision></link>
  <joint name="turn" type="revolute"><parent link="base"/><child link="column"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="60" velocity="2"/></joint>
  <link name="column"><inertial><origin xyz="0 0 0.05"/><mass value="2"/><inertia ixx="0.005" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.005"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.08 0.08 0.1"/></geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="column"/><child link="upper"/><origin xyz="0 0 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="60" velocity="2"/></joint>
  <link name="upper"><inertial><origin xyz="0 0 0.2"/><mass value="1.5"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.001"/></inertial>
    <collision><origin xyz="0 0 0.2"/><geometry><box size="0.05 0.05 0.4"/></geometry></collision></link>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="40" velocity="2"/></joint>
  <link name="fore"><inertial><origin xyz="0 0 0.15"/><mass value="1"/><inertia ixx="0.008" ixy="0" ixz="0" iyy="0.008" iyz="0" izz="0.001"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><box size="0.04 0.04 0.3"/></geometry></collision></link>
  <joint name="flange" type="fixed"><parent link="fore"/><child link="tool"/><origin xyz="0 0 0.3"/></joint>
  <link name="tool"/>
</robot>"#;

const ROBOT_FILE: &str = r#"urdf = "arm3.urdf"
base = "base"
tool = "tool"
joints = ["turn", "shoulder", "elbow"]
control_period = 0.008
command = "speed"
home = [0.0, 0.5, 1.0]
"#;

/// A six-joint arm of boxes in a UR's order of axes: a base turning about z, shoulder, elbow
/// and wrist 1 about y, wrist 2 about z, wrist 3 about y, the tool 0.1 m past it on a 1 kg hand
/// (a tool changer and cup's worth).
const URDF6: &str = r#"<robot name="arm6">
  <link name="base"><inertial><origin xyz="0 0 0.05"/><mass value="5"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.02"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><cylinder radius="0.08" length="0.1"/></geometry></collision></link>
  <joint name="turn" type="revolute"><parent link="base"/><child link="column"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="80" velocity="2"/></joint>
  <link name="column"><inertial><origin xyz="0 0 0.05"/><mass value="2"/><inertia ixx="0.005" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.005"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.08 0.08 0.1"/></geometry></collision></link>
  <joint name="shoulder" type="revolute"><parent link="column"/><child link="upper"/><origin xyz="0 0 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="80" velocity="2"/></joint>
  <link name="upper"><inertial><origin xyz="0 0 0.2"/><mass value="1.5"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.001"/></inertial>
    <collision><origin xyz="0 0 0.2"/><geometry><box size="0.05 0.05 0.4"/></geometry></collision></link>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="60" velocity="2"/></joint>
  <link name="fore"><inertial><origin xyz="0 0 0.15"/><mass value="1"/><inertia ixx="0.008" ixy="0" ixz="0" iyy="0.008" iyz="0" izz="0.001"/></inertial>
    <collision><origin xyz="0 0 0.15"/><geometry><box size="0.04 0.04 0.3"/></geometry></collision></link>
  <joint name="wrist_1" type="revolute"><parent link="fore"/><child link="wrist_a"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="20" velocity="2"/></joint>
  <link name="wrist_a"><inertial><origin xyz="0 0 0.05"/><mass value="0.3"/><inertia ixx="0.0005" ixy="0" ixz="0" iyy="0.0005" iyz="0" izz="0.0002"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.03 0.03 0.08"/></geometry></collision></link>
  <joint name="wrist_2" type="revolute"><parent link="wrist_a"/><child link="wrist_b"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="20" velocity="2"/></joint>
  <link name="wrist_b"><inertial><origin xyz="0 0 0.05"/><mass value="0.3"/><inertia ixx="0.0005" ixy="0" ixz="0" iyy="0.0005" iyz="0" izz="0.0002"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.03 0.03 0.08"/></geometry></collision></link>
  <joint name="wrist_3" type="revolute"><parent link="wrist_b"/><child link="hand"/><origin xyz="0 0 0.1"/><axis xyz="0 1 0"/>
    <limit lower="-2.5" upper="2.5" effort="20" velocity="2"/></joint>
  <link name="hand"><inertial><origin xyz="0 0 0.05"/><mass value="1"/><inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.001"/></inertial>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.03 0.03 0.08"/></geometry></collision></link>
  <joint name="flange" type="fixed"><parent link="hand"/><child link="tool"/><origin xyz="0 0 0.1"/></joint>
  <link name="tool"/>
</robot>"#;

pub const ROBOT_FILE6: &str = r#"urdf = "arm6.urdf"
base = "base"
tool = "tool"
joints = ["turn", "shoulder", "elbow", "wrist_1", "wrist_2", "wrist_3"]
control_period = 0.008
command = "speed"
home = [0.0, 0.5, 1.0, 0.5, 0.0, 0.0]
"#;

/// A cell for the six-joint arm: its base on a table top 0.75 m up, the fixtures 0.47 m out,
/// where its tool reaches pointing down.
const CELL6: &str = r#"[table]
centre = [0.3, 0.0]
size = [1.0, 1.0]
height = 0.75

[robot]
position = [0.0, 0.0]

[pick]
position = [0.45, 0.15]

[place]
position = [0.45, -0.15]
"#;

/// The three-joint arm's robot file in a folder of its own.
fn robot_file(name: &str) -> PathBuf {
    robot_file_of(name, "arm3", URDF, ROBOT_FILE)
}

/// The six-joint arm's robot file in a folder of its own.
pub fn six_joint_robot_file(name: &str) -> PathBuf {
    robot_file_of(name, "arm6", URDF6, ROBOT_FILE6)
}

/// The six-joint arm's robot file with its cell ([`CELL6`]) and a vacuum cup, in a folder of
/// its own.
pub fn six_joint_cell_robot_file(name: &str) -> PathBuf {
    let keys = "cell = \"cell.toml\"\n[gripper]\nradius = 0.02\nstroke = 0.015\n";
    let path = robot_file_of(name, "arm6", URDF6, &format!("{ROBOT_FILE6}{keys}"));
    std::fs::write(path.with_file_name("cell.toml"), CELL6).unwrap();
    path
}

fn robot_file_of(name: &str, arm: &str, urdf: &str, file: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-arm-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(format!("{arm}.urdf")), urdf).unwrap();
    std::fs::write(dir.join(format!("{arm}.toml")), file).unwrap();
    dir.join(format!("{arm}.toml"))
}

fn env(path: &Path, arenas: usize) -> AppVecEnv {
    let robot = twinbots_arm::robot(path).unwrap();
    AppVecEnv::new(robot.app(None, arenas, 7, DesignPattern::Supervised).unwrap())
}

#[test]
fn a_robot_file_arm_follows_its_kinematics_and_a_resolved_rate_controller_reaches() {
    let path = robot_file("reach");
    let file = RobotFile::read(&path).unwrap();
    let mut env = env(&path, 2);
    let mut obs = env.reset(Some(3)).unwrap();
    let dim = obs.len() / 2;
    assert_eq!(dim, 9 + 3 * 3, "tool, offset, tool velocity, then 3 values per joint");
    let (mut arrived, mut ended) = (0, 0);
    let mut worst_tool_error = 0.0f32;
    for _ in 0..800 {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(|o| resolved_rate(&file, o)).collect();
        let step = env.step(&actions).unwrap();
        for (i, summary) in step.episodes.iter().enumerate() {
            if let Some(summary) = summary {
                ended += 1;
                arrived += usize::from(summary.success == Some(true));
                // Every reach spends energy moving the arm, metered every physics step.
                let energy = summary.metrics["energy_j"];
                assert!(energy.is_finite() && energy > 0.0, "energy {energy} J");
                assert_ne!(step.way_ended(i).as_deref(), Some(STOP_TERM), "the controller stays inside the ranges");
            }
        }
        obs = step.obs;
        // The twin's tool link where the controller's kinematics put it.
        let world = env.app().world();
        let links = world.iter_entities().filter_map(|e| Some((e.get::<Link>()?, e.get::<InArena>()?)));
        for (link, in_arena) in links {
            if link.name != "tool" {
                continue;
            }
            let physics = physics_in(world, in_arena.0).unwrap();
            let simulated = (*physics.bodies[link.body].position() * link.offset).translation;
            let state = world.get::<ReachState>(in_arena.0).unwrap();
            worst_tool_error = worst_tool_error.max((simulated - state.tool).length());
        }
    }
    assert!(worst_tool_error < 0.003, "the twin's tool is {worst_tool_error} m from the controller's kinematics");
    assert!(ended >= 10 && arrived as f32 >= 0.9 * ended as f32, "{arrived} of {ended} reaches arrived");
}

#[test]
fn a_joint_driven_into_its_stop_ends_the_reach_in_a_protective_stop() {
    let mut env = env(&robot_file("stop"), 1);
    env.reset(Some(1)).unwrap();
    let mut ended_by = None;
    for step in 0..100 {
        let result = env.step(&[0.0, 0.0, 1.0]).unwrap();
        if result.episodes[0].is_some() {
            ended_by = result.way_ended(0);
            // The elbow's 1.5 rad to its stop at 1 rad/s (half of 2): about 38 steps of 40 ms.
            assert!((30..60).contains(&step), "ended at step {step}");
            break;
        }
    }
    assert_eq!(ended_by.as_deref(), Some(STOP_TERM));
}

#[test]
fn a_speed_command_ramps_within_the_files_acceleration_limits() {
    // The elbow's speed (joint_velocities[2]) after each control step of 40 ms at full action.
    let elbow_speeds = |path: &Path| {
        let mut env = env(path, 1);
        env.reset(Some(4)).unwrap();
        (0..15).map(|_| env.step(&[0.0, 0.0, 1.0]).unwrap().obs[9 + 3 + 2]).collect::<Vec<f32>>()
    };
    // Without the key the drive takes the task's 1 rad/s (half the URDF's 2) within one step.
    let free = elbow_speeds(&robot_file("free"));
    assert!(free[0] > 0.9, "{free:?}");
    // 4 rad/s² in the file, half by the safety factor: 0.08 rad/s a control step, 1 rad/s at 0.5 s.
    let path = robot_file_of("ramped", "arm3", URDF, &format!("{ROBOT_FILE}acceleration_limits = [4, 4, 4]\n"));
    assert_eq!(RobotFile::read(&path).unwrap().acceleration_limits, Some(vec![2.0; 3]));
    let ramped = elbow_speeds(&path);
    for (k, speed) in ramped.iter().enumerate() {
        let ramp = (2.0 * 0.04 * (k + 1) as f32).min(1.0);
        assert!((speed - ramp).abs() < 0.03, "step {k}: {speed} rad/s against the ramp's {ramp}: {ramped:?}");
    }
}

#[test]
fn a_robot_file_arm_in_its_cell_picks_and_places_the_part_with_its_classical_controller() {
    let path = six_joint_cell_robot_file("pick");
    let file = RobotFile::read(&path).unwrap();
    let robot = twinbots_arm::robot(&path).unwrap();
    let tasks: Vec<&str> = robot.tasks.iter().map(|t| t.name).collect();
    assert_eq!(tasks, ["reach", "pick-place", "pick-place-learned"]);
    let mut env = AppVecEnv::new(robot.app(Some("pick-place"), 2, 5, DesignPattern::Supervised).unwrap());
    let mut obs = env.reset(Some(5)).unwrap();
    let dim = obs.len() / 2;
    let (mut placed, mut ended) = (0, 0);
    while ended < 6 {
        // The classical controller makes the free moves; the program's straight moves are its own.
        let actions: Vec<f32> = obs.chunks(dim).flat_map(|o| resolved_rate(&file, o)).collect();
        let step = env.step(&actions).unwrap();
        for summary in step.episodes.iter().flatten() {
            ended += 1;
            let metrics = &summary.metrics;
            let outcomes: f32 = metrics.iter().filter(|(k, _)| k.starts_with("outcome_")).map(|(_, v)| v).sum();
            assert_eq!(outcomes, 1.0, "one outcome per episode: {metrics:?}");
            if summary.success == Some(true) {
                placed += 1;
                assert!(metrics["cycle_time_s"] > 1.0 && metrics["place_offset_mm"] < 16.0, "{metrics:?}");
            }
        }
        obs = step.obs;
    }
    assert!(placed >= 5, "{placed} of {ended} programs placed the part");

    // A held joint must be a movable joint outside `joints`.
    let held = robot_file_of("held", "arm6", URDF6, &format!("{ROBOT_FILE6}[held_positions]\nelbow = 0.1\n"));
    let Err(err) = twinbots_arm::robot(&held) else { panic!("a controlled joint held") };
    let err = format!("{err:#}");
    assert!(err.contains("key 'held_positions': 'elbow' is not a movable joint of the URDF outside"), "{err}");

    // A cell whose plates overlap is named with the robot file's key.
    std::fs::write(path.with_file_name("cell.toml"), CELL6.replace("[0.45, -0.15]", "[0.45, 0.1]")).unwrap();
    let Err(err) = twinbots_arm::robot(&path) else { panic!("a bad cell read") };
    let err = format!("{err:#}");
    assert!(err.contains("arm6.toml: key 'cell'") && err.contains("overlaps the pick fixture's"), "{err}");
}

/// Pick-and-place learned end to end on a robot file's arm in its cell: the goal's terms lie
/// where the goal interface reads them, parts start and goals lie on the free table in reach,
/// and the scripted baseline (`classic`) meets the goals in the twin, on the table and in the
/// air; a met goal is met under hindsight's judgement too.
#[test]
fn a_robot_file_arm_in_its_cell_takes_the_part_to_learned_pick_and_places_goals() {
    let path = six_joint_cell_robot_file("learned");
    let robot = twinbots_arm::robot(&path).unwrap();
    let task = robot.tasks.iter().find(|t| t.name == "pick-place-learned").expect("an arm with a cell learns it");
    assert!(task.training.is_some() && task.scripted.is_some());
    let spec = (task.spec)();
    let at = |name: &str| spec.observation_names.iter().position(|n| n == name).unwrap();
    let terms = twinbots_arm::pick_place_learned::GOAL_TERMS;
    assert_eq!(
        [at("tool_position[0]"), at("part_position[0]"), at("part_velocity[0]"), at("suction")],
        [terms.tcp_position, terms.part_position, terms.part_velocity, terms.suction]
    );
    assert_eq!([at("holding"), at("goal_position[0]")], [terms.holding, terms.goal_position]);
    assert_eq!(spec.observation_names.len(), 20 + 6);
    let goal = spec.goal.expect("goal-conditioned");

    let arm = twinbots_arm::Arm::of(RobotFile::read(&path).unwrap()).unwrap();
    let area = arm.work_area.clone().expect("a work area");
    let [lo, hi] = area.bounds();
    for corner in [lo, hi, Vec2::new(lo.x, hi.y), Vec2::new(hi.x, lo.y)] {
        let grip = corner.extend(area.table + 0.05);
        assert!(arm.reachable(grip), "the area's corner {corner} out of reach");
    }

    let mut env = AppVecEnv::new(robot.app(Some("pick-place-learned"), 4, 3, DesignPattern::Supervised).unwrap());
    let mut obs = env.reset(Some(3)).unwrap();
    let dim = obs.len() / 4;
    let (mut met, mut ended, mut in_air, mut met_in_air) = (0, 0, 0, 0);
    while ended < 24 {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(twinbots_arm::pick_place_learned::scripted).collect();
        let step = env.step(&actions).unwrap();
        for (i, summary) in step.episodes.iter().enumerate() {
            let Some(summary) = summary else { continue };
            ended += 1;
            let last = step.final_obs[i].as_deref().expect("an ended episode's last observation");
            assert!(area.contains(Vec2::new(last[terms.goal_position], last[terms.goal_position + 1])));
            in_air += usize::from(summary.metrics["goal_in_air"] > 0.5);
            if summary.success == Some(true) {
                met += 1;
                met_in_air += usize::from(summary.metrics["goal_in_air"] > 0.5);
                assert!(summary.metrics["final_distance_mm"] < 20.0, "{:?}", summary.metrics);
                let (desired, achieved) = ((goal.desired)(last), (goal.achieved)(last));
                assert!((goal.change)(last, last, None, &desired, &achieved).ends_at_to, "{:?}", summary.metrics);
            }
        }
        obs = step.obs;
    }
    // Measured: 23 of 24 (on a hand of 0.2 kg, 11: its wrist whipped past its speed limit by
    // the part it carried).
    assert!(
        met >= 21 && met_in_air >= 1 && met_in_air < met,
        "the scripted baseline met {met} of {ended} goals ({met_in_air} of {in_air} in the air)"
    );
}

#[test]
fn a_forearm_knocked_beyond_the_elbows_speed_limit_trips_the_safety_systems_stop() {
    let mut env = env(&robot_file("knock"), 1);
    env.reset(Some(2)).unwrap();
    let world = env.app_mut().world_mut();
    let fore = world
        .query::<(bevy::prelude::Entity, &Link)>()
        .iter(world)
        .find(|(_, link)| link.name == "fore")
        .map(|(entity, _)| entity)
        .unwrap();
    // A blow across the forearm's tip for one 4 ms physics step: 8 N·s whips the elbow far past
    // its 2 rad/s at once, long before it could travel the 1.5 rad to its range's end.
    let blow =
        twinbots_sim::Push::lasting(bevy::math::Vec3::X * 2000.0, bevy::math::Vec3::new(0.0, 0.0, 0.3), 0.004, 0.004);
    world.entity_mut(fore).insert(blow);
    let step = env.step(&[0.0, 0.0, 0.0]).unwrap();
    assert!(step.episodes[0].is_some(), "the stop ends the reach the step it trips");
    assert_eq!(step.way_ended(0).as_deref(), Some(STOP_TERM));
    // The reset unlocked it, filters and all.
    let world = env.app_mut().world_mut();
    let state = world.query::<&ReachState>().single(world).unwrap();
    assert_eq!(state.safety, twinbots_task::safety::Safety::default());
}

#[test]
fn hindsight_goals_are_rewarded_as_the_task_rewards_them() {
    let path = robot_file("goal");
    let mut env = env(&path, 1);
    let spec = twinbots_arm::robot(&path).unwrap().task();
    let goal = spec.goal.unwrap();
    let obs = env.reset(Some(5)).unwrap();
    let step = env.step(&[0.3, -0.2, 0.1]).unwrap();
    let next = step.obs.clone();
    // The step's own goal: the change to itself is nothing.
    let desired = (goal.desired)(&next);
    let same = (goal.change)(&obs, &next, None, &desired, &desired);
    assert_eq!(same.reward, 0.0);
    // The goal where the tool is now: the distance terms vanish and, were the tool at rest, it
    // would arrive.
    let achieved = (goal.achieved)(&next);
    let change = (goal.change)(&obs, &next, None, &desired, &achieved);
    let distance =
        ((desired[0] - achieved[0]).powi(2) + (desired[1] - achieved[1]).powi(2) + (desired[2] - achieved[2]).powi(2))
            .sqrt();
    let expected_gain = distance + 0.1 * (1.0 - (-(distance / 0.02).powi(2)).exp());
    let speed = (next[6] * next[6] + next[7] * next[7] + next[8] * next[8]).sqrt();
    let bonus = if speed < 0.05 { 10.0 } else { 0.0 };
    assert!((change.reward - expected_gain - bonus).abs() < 1e-4, "{change:?}, distance {distance}");
    assert_eq!(change.ends_at_to, speed < 0.05);
}

#[test]
fn a_robot_file_arm_is_served_under_design_pattern_3_and_homes_itself() {
    use twinbots_learn::{Flow, Ppo};
    use twinbots_server::server::{RobotServer, ServerSettings};

    let path = robot_file("served");
    let robot = twinbots_arm::robot(&path).unwrap();
    let spec = robot.task();
    let learner = Box::new(
        Ppo::new(
            robot.defaults.of("ppo").config().unwrap(),
            spec.observation_space.clone(),
            spec.action_space.clone(),
            1,
        )
        .unwrap(),
    );
    let settings = ServerSettings::new(robot.name, &spec, 2, 512);
    let count = |_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue);
    let server = RobotServer::start("127.0.0.1:0".parse().unwrap(), learner, settings, Box::new(count)).unwrap();
    let mut app = crate::server::robots_against(&robot, server.addr);
    let run = crate::server::run_robots_until_done(&mut app, 20_000);
    assert!(run.episodes > 0);
    let (served, _) = server.wait().unwrap();
    assert!(served.timesteps() >= 512, "{} steps", served.timesteps());
}

/// The built-in UR5e's kinematics, written out from UR's DH table (its fast path), equal its
/// robot file's URDF chain (`assets/robots/ur5e.toml`): the tool face's pose and the geometric
/// Jacobian at 1,000 random configurations, within what the URDF's six-digit angles allow.
#[test]
fn the_ur5es_written_out_kinematics_equal_its_robot_files_chain() {
    use bevy::math::DQuat;
    use rand::{Rng, SeedableRng};
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/robots/ur5e.toml");
    let file = RobotFile::read(&path).unwrap();
    assert_eq!(file.joints, ur5e::kinematics::JOINTS);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let (mut worst_position, mut worst_angle, mut worst_column) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..1000 {
        let q: [f32; 6] = std::array::from_fn(|_| rng.random_range(-3.0f32..3.0));
        let chain_q: Vec<f64> = q.iter().map(|&v| v as f64).collect();
        let dh = ur5e::kinematics::tool_face(ur5e::kinematics::frames(&q)[6]);
        let urdf = file.chain.forward(&chain_q);
        worst_position = worst_position.max((dh.w_axis.truncate() - urdf.translation).length());
        let rotation = DQuat::from_mat4(&dh);
        worst_angle = worst_angle.max(rotation.angle_between(urdf.rotation));
        let (written, columns) = (ur5e::kinematics::jacobian(&q), file.chain.jacobian(&chain_q));
        for (a, b) in written.iter().zip(&columns) {
            worst_column = worst_column.max(a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max));
        }
    }
    assert!(worst_position < 2e-6, "tool face {worst_position} m apart");
    assert!(worst_angle < 2e-6, "tool face turned {worst_angle} rad apart");
    assert!(worst_column < 2e-6, "Jacobian entries {worst_column} apart");
}

/// A robot file's arm has a classical controller (`classic`: resolved-rate control over the
/// reach's observation), so `demos` writes a LeRobot dataset of its reaches with no training.
#[test]
fn a_robot_file_arms_classical_controller_records_demonstrations() {
    let path = robot_file("demos");
    let out = path.with_file_name("demos");
    let _ = std::fs::remove_dir_all(&out);
    let output =
        crate::delivery::twinbots().arg("demos").arg(&path).args(["--episodes", "6", "--out"]).arg(&out).output();
    let stdout = crate::delivery::succeeded(output.unwrap());
    let met: usize = stdout
        .split_once("frames (")
        .and_then(|(_, rest)| rest.split_once(" of 6 episodes run met the goal"))
        .map(|(n, _)| n.parse().unwrap())
        .unwrap_or_else(|| panic!("{stdout}"));
    assert!(met >= 5, "{stdout}");
    let info: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(info["total_episodes"], 6, "{info}");
}
