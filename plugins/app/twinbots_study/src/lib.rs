//! Studies (`twinbots study <robot> FILE.toml`, docs/studies.md). For the pendulums, a policy
//! test suite: every test of the suite, for every controller and seed, each run in its own arena
//! of one app per controller, side by side; a run records its time series, its figures come
//! from [`metrics`], [`report`] writes the files. For a robot with a cell, a cell study
//! ([`cell`]): layouts, speeds, payloads, latencies and failure scenarios swept.

pub mod cell;
pub mod controller;
pub mod demos;
pub mod distill;
pub mod metrics;
pub mod report;
pub mod suite;

use std::path::Path;

use bevy::prelude::*;
use serde::Serialize;
use twinbots_api::VecEnv;
use twinbots_sim::{Arena, InArena, Link, Push, SimSettings, SupervisorAccess, add_link_mass};

use self::controller::{NamedController, open_all, reset_alike};
use self::metrics::Response;
use self::suite::{NamedTest, Suite, Test};
use twinbots_run::registry::RobotEntry;

/// One run's record: its test, what happened and its figures.
#[derive(Clone, Debug, Serialize)]
pub struct RunRecord {
    /// The controller's label (its results' folder) and how the study named it.
    pub controller: String,
    pub controller_spec: String,
    pub test: String,
    pub kind: &'static str,
    pub seed: u64,
    /// Push (N, along the suite's direction), its start and length (s); 0 for payloads.
    pub force_n: f64,
    pub at_s: f64,
    pub push_s: f64,
    /// The payload link's mass (kg), if the test sets it.
    pub payload_kg: Option<f64>,
    /// The run lasted the suite's duration without the task ending it.
    pub survived: bool,
    /// When the task ended it (s), and which termination term.
    pub ended_s: Option<f64>,
    pub ended_by: Option<String>,
    pub response: Response,
    /// Column names of `series` rows: `time_s`, the observation's names, `action_*`, `push_n`.
    #[serde(skip)]
    pub columns: Vec<String>,
    #[serde(skip)]
    pub series: Vec<Vec<f64>>,
}

/// A study's results, ready to write.
pub struct StudyResult {
    pub robot: String,
    pub suite: Suite,
    pub signal_column: usize,
    pub runs: Vec<RunRecord>,
}

/// Runs `suite` on `entry`'s twin, with `controllers` instead of the suite's when given
/// (relative paths from the working directory then; from the suite's folder otherwise).
pub fn run_suite(entry: &RobotEntry, suite_path: &Path, controllers: &[String]) -> anyhow::Result<StudyResult> {
    let suite = Suite::read(suite_path)?;
    if let Some(robot) = &suite.robot {
        anyhow::ensure!(
            robot == entry.name,
            "{}: robot = '{robot}', but the study runs {}",
            suite_path.display(),
            entry.name
        );
    }
    let named = open_all(entry, suite_path, &suite.controllers, controllers)?;
    let spec = (entry.main_task().spec)();
    let signal = spec.observation_names.iter().position(|n| *n == suite.signal).ok_or_else(|| {
        anyhow::anyhow!(
            "{}: signal = '{}': {}'s observation has {}",
            suite_path.display(),
            suite.signal,
            entry.name,
            spec.observation_names.join(", ")
        )
    })?;
    let mut runs = Vec::new();
    for controller in &named {
        let started = std::time::Instant::now();
        let done = run_controller(entry, &suite, controller)
            .map_err(|e| anyhow::anyhow!("{}: {e:#}", suite_path.display()))?;
        let survived = done.iter().filter(|r| r.survived).count();
        println!(
            "{}: {} runs, {survived} survived, {:.1} s",
            controller.label,
            done.len(),
            started.elapsed().as_secs_f64()
        );
        runs.extend(done);
    }
    Ok(StudyResult { robot: entry.name.to_string(), suite, signal_column: signal + 1, runs })
}

/// Every test × seed of the suite for one controller: one arena each, stepped together.
fn run_controller(entry: &RobotEntry, suite: &Suite, controller: &NamedController) -> anyhow::Result<Vec<RunRecord>> {
    // How many tests there are does not depend on the control step; how long a kick lasts does.
    let runs = suite.tests(1.0).len() * suite.seeds.len();
    let mut env = controller.env(entry, None, runs, suite.seeds[0], |app| {
        add_payloads(app);
        Ok(())
    })?;
    let settings = *env.app().world().resource::<SimSettings>();
    let control_dt = settings.control_seconds();
    let tests = suite.tests(control_dt);
    let plan: Vec<(&NamedTest, u64)> = tests.iter().flat_map(|t| suite.seeds.iter().map(move |&s| (t, s))).collect();
    let arenas = env.arenas().to_vec();
    let push_link = find_links(env.app_mut().world_mut(), &arenas, &suite.push.link)?;
    for (i, (test, _)) in plan.iter().enumerate() {
        if let Test::Payload { link, mass } = &test.test {
            let payload = payload(entry, env.app_mut().world_mut(), arenas[i], link, *mass)?;
            env.app_mut().world_mut().entity_mut(arenas[i]).insert(payload);
        }
    }
    // Every run starts as the suite's first arena would from its seed, whichever arena it has.
    let seeds: Vec<u64> = plan.iter().map(|(_, s)| *s).collect();
    let mut obs = reset_alike(&mut env, &seeds)?;
    let dim = env.observation_space().dim();
    let actions_dim = env.action_space().dim();
    let spec = env.task().clone();
    let mut columns = vec!["time_s".to_string()];
    columns.extend(spec.observation_names.iter().cloned());
    columns.extend((0..actions_dim).map(|j| format!("action_{j}")));
    columns.push("push_n".into());
    let direction = Vec3::from(suite.push.direction).normalize();
    let steps = (suite.duration / control_dt).round() as usize;
    // Pushes start at the first control step at or after their time and last whole physics steps.
    let pushes: Vec<Option<(usize, f64, u32)>> = plan
        .iter()
        .map(|(test, _)| match test.test {
            Test::Push { force, at, seconds } => {
                let push = Push::lasting(Vec3::ZERO, Vec3::ZERO, seconds as f32, settings.dt);
                Some(((at / control_dt - 1e-9).ceil() as usize, force, push.physics_steps))
            }
            Test::Payload { .. } => None,
        })
        .collect();
    let mut records: Vec<RunRecord> =
        plan.iter().map(|(test, seed)| record(controller, test, *seed, &columns)).collect();
    for (r, push) in records.iter_mut().zip(&pushes) {
        if let Some((start, _, physics_steps)) = push {
            r.at_s = *start as f64 * control_dt;
            r.push_s = f64::from(*physics_steps) * settings.dt_seconds();
        }
    }
    let mut live = vec![true; plan.len()];
    for k in 0..steps {
        let t = k as f64 * control_dt;
        for (i, push) in pushes.iter().enumerate() {
            if let Some((start, force, physics_steps)) = *push
                && live[i]
                && k == start
            {
                let push = Push { force: direction * force as f32, point: Vec3::from(suite.push.point), physics_steps };
                env.app_mut().world_mut().entity_mut(push_link[i]).insert(push);
            }
        }
        let actions = controller.act(&obs, dim)?;
        for i in (0..plan.len()).filter(|&i| live[i]) {
            // The force during this control step (a push that ends inside it still counts).
            let pushing = match pushes[i] {
                Some((start, force, physics_steps))
                    if k >= start && (k - start) * (settings.substeps as usize) < physics_steps as usize =>
                {
                    force
                }
                _ => 0.0,
            };
            let mut row = vec![t];
            row.extend(obs[i * dim..(i + 1) * dim].iter().map(|&v| f64::from(v)));
            row.extend(actions[i * actions_dim..(i + 1) * actions_dim].iter().map(|&v| f64::from(v)));
            row.push(pushing);
            records[i].series.push(row);
        }
        let out = env.step(&actions)?;
        for i in 0..plan.len() {
            // A world whose numbers left the plausible (a push the physics could not take)
            // ends its run as a fall would: it did not survive, whatever the task says.
            if live[i] && out.obs[i * dim..(i + 1) * dim].iter().any(|v| !v.is_finite() || v.abs() > BLOWN_UP) {
                live[i] = false;
                let end = (k + 1) as f64 * control_dt;
                records[i].survived = false;
                records[i].ended_s = Some(end);
                records[i].ended_by = Some("physics_blew_up".into());
                continue;
            }
            if !live[i] || !(out.terminated[i] || out.truncated[i]) {
                continue;
            }
            live[i] = false;
            let end = (k + 1) as f64 * control_dt;
            anyhow::ensure!(
                out.terminated[i] || k + 1 == steps,
                "duration = {} s outlasts {}'s episodes (the task ends them after {end:.2} s): make it shorter",
                suite.duration,
                entry.name
            );
            if out.terminated[i] {
                records[i].series.push(last_row(end, out.final_obs[i].as_deref().unwrap_or(&[]), actions_dim));
                records[i].survived = false;
                records[i].ended_s = Some(end);
                records[i].ended_by = out.ended_by[i].clone();
            }
        }
        obs = out.obs;
    }
    for (i, r) in records.iter_mut().enumerate() {
        if live[i] {
            r.series.push(last_row(steps as f64 * control_dt, &obs[i * dim..(i + 1) * dim], actions_dim));
        }
        let signal = 1 + spec.observation_names.iter().position(|n| *n == suite.signal).unwrap_or(0);
        let t: Vec<f64> = r.series.iter().map(|row| row[0]).collect();
        let y: Vec<f64> = r.series.iter().map(|row| row[signal]).collect();
        r.response = metrics::disturbance(&t, &y, r.at_s, suite.setpoint, suite.settle_band, suite.window);
    }
    Ok(records)
}

/// An observation beyond this (or not a number) is a world the physics lost.
pub const BLOWN_UP: f32 = 1e6;

/// A run's last row: its final state, no action after it, no push.
fn last_row(time: f64, obs: &[f32], actions_dim: usize) -> Vec<f64> {
    let mut row = vec![time];
    row.extend(obs.iter().map(|&v| f64::from(v)));
    row.extend(std::iter::repeat_n(f64::NAN, actions_dim));
    row.push(0.0);
    row
}

fn record(controller: &NamedController, test: &NamedTest, seed: u64, columns: &[String]) -> RunRecord {
    let (force_n, at_s, push_s, payload_kg) = match &test.test {
        Test::Push { force, at, seconds } => (*force, *at, *seconds, None),
        Test::Payload { mass, .. } => (0.0, 0.0, 0.0, Some(*mass)),
    };
    RunRecord {
        controller: controller.label.clone(),
        controller_spec: controller.spec.clone(),
        test: test.name.clone(),
        kind: test.kind,
        seed,
        force_n,
        at_s,
        push_s,
        payload_kg,
        survived: true,
        ended_s: None,
        ended_by: None,
        response: Response::default(),
        columns: columns.to_vec(),
        series: Vec::new(),
    }
}

/// The entity of the link named `name` in each arena; an unknown name lists the robot's links.
fn find_links(world: &mut World, arenas: &[Entity], name: &str) -> anyhow::Result<Vec<Entity>> {
    let links: Vec<(Entity, String, Entity)> =
        world.query::<(Entity, &Link, &InArena)>().iter(world).map(|(e, l, a)| (e, l.name.clone(), a.0)).collect();
    arenas
        .iter()
        .map(|&arena| {
            links.iter().find(|(_, n, a)| n == name && *a == arena).map(|(e, _, _)| *e).ok_or_else(|| {
                let mut names: Vec<&str> =
                    links.iter().filter(|(_, _, a)| *a == arena).map(|(_, n, _)| n.as_str()).collect();
                names.sort_unstable();
                anyhow::anyhow!("link '{name}' is not one of the robot's: {}", names.join(", "))
            })
        })
        .collect()
}

/// Mass added to a link of an arena's robot at its origin (kg; negative takes it away), put on
/// at every reset (a reset restores the URDF's): a study's payload, on the arena's entity.
#[derive(Component, Clone, Copy, Debug)]
pub struct Payload {
    pub link: Entity,
    pub extra_kg: f32,
}

/// Puts the arenas' [`Payload`]s on at every reset; a study's app calls it before its start-up.
pub fn add_payloads(app: &mut App) {
    app.add_systems(twinbots_task::task::EnvReset, put_on_payloads.in_set(twinbots_task::task::ResetSet::Place));
}

fn put_on_payloads(
    privilege: Res<SupervisorAccess>,
    arenas: Query<(Entity, &Payload), With<twinbots_task::task::Resetting>>,
    links: Query<&Link>,
    mut worlds: Query<&mut Arena>,
) {
    for (arena, payload) in &arenas {
        if let (Ok(link), Ok(mut world)) = (links.get(payload.link), worlds.get_mut(arena)) {
            // Checked when the payload was made: the link's body keeps a positive mass.
            let _ = add_link_mass(world.physics_mut(&privilege), link, payload.extra_kg);
        }
    }
}

/// The payload that makes the link's mass `mass` (kg) in one arena: the difference to its URDF
/// mass, checked against the link's body.
fn payload(entry: &RobotEntry, world: &mut World, arena: Entity, link: &str, mass: f64) -> anyhow::Result<Payload> {
    let rig = entry
        .rig
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("payload: {} has no robot model to take the link's mass from", entry.name))?;
    let model = (rig.model)();
    let nominal = model
        .links
        .iter()
        .find(|l| l.name == link)
        .ok_or_else(|| anyhow::anyhow!("payload.link = '{link}' is not one of {}'s links", entry.name))?
        .inertial
        .map_or(0.0, |i| i.mass);
    let entity = find_links(world, &[arena], link)?[0];
    let link_component = world.get::<Link>(entity).cloned().expect("found as a link");
    let extra_kg = mass as f32 - nominal;
    // Put on once now, which checks it; the reset that starts the runs restores the URDF's mass
    // and puts it on again, as every later reset does.
    let mut physics = twinbots_sim::physics_in_mut(world, arena)
        .ok_or_else(|| anyhow::anyhow!("payload: the study's app does not grant the Supervisor"))?;
    add_link_mass(&mut physics, &link_component, extra_kg).map_err(|e| anyhow::anyhow!("payload: {e}"))?;
    Ok(Payload { link: entity, extra_kg })
}
