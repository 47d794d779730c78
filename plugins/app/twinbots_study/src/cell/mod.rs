//! Cell studies (`twinbots study ur5e STUDY.toml`, `twinbots study ARM.toml STUDY.toml`,
//! docs/studies.md): the pick-and-place cell under every combination of layout, speed slider,
//! payload, command latency and failure scenario, for each controller, N episodes each, one
//! arena per combination, side by side. A production engineer's figures per episode (success,
//! outcome, cycle time and its phases, energy, collisions, protective stops, reach failures)
//! and per combination. The arm is the UR5e or a robot file's arm with a cell and a gripper
//! ([`CellArm`]).

pub mod arm;
pub mod plan;
pub mod plots;
pub mod report;

use std::collections::VecDeque;
use std::path::Path;
use std::time::Instant;

use bevy::prelude::*;
use serde::Serialize;
use twinbots_api::{EpisodeSummary, VecEnv};
use twinbots_sim::{Push, SimSettings, VacuumGripper};
use twinbots_task::cell::layout::{CellLayout, CellLayouts};
use twinbots_task::cell::parts::CellFurniture;
use twinbots_task::cell::program::{EPISODE_STEPS, SpeedSlider, Stage, waypoint};

pub use self::arm::{CellArm, PlacedArm};
use self::plan::{CellStudy, Combination, Failure};
use super::controller::{NamedController, open_all, reset_alike};
use super::{Payload, add_payloads};
use twinbots_run::registry::RobotEntry;

/// The program's phases, in order, as the breakdown names them.
pub const PHASES: [(Stage, &str); 9] = [
    (Stage::Approach, "approach"),
    (Stage::Descend, "descend"),
    (Stage::Grip, "grip"),
    (Stage::Lift, "lift"),
    (Stage::Transfer, "transfer"),
    (Stage::Align, "align"),
    (Stage::Lower, "lower"),
    (Stage::Release, "release"),
    (Stage::Retract, "retract"),
];

/// Arenas per app: larger sweeps run in batches.
const BATCH: usize = 64;

/// One episode of a combination.
#[derive(Clone, Debug, Serialize)]
pub struct EpisodeRecord {
    pub combination: usize,
    pub episode: usize,
    pub success: bool,
    pub outcome: String,
    pub cycle_time_s: Option<f64>,
    pub energy_j: f64,
    pub collision_events: u32,
    pub joint_limit_events: u32,
    pub protective_stops: u32,
    /// The program sent the arm to a waypoint it cannot reach ([`PlacedArm::reachable`]).
    pub reach_failure: bool,
    pub steps: u32,
    /// Seconds spent in each of [`PHASES`].
    pub phases_s: [f64; 9],
}

/// A study's results.
pub struct CellStudyResult {
    pub robot: String,
    pub study: CellStudy,
    pub controllers: Vec<String>,
    pub layouts: Vec<(String, CellLayout)>,
    /// The arm in each of the layouts.
    pub arms: Vec<PlacedArm>,
    pub combinations: Vec<Combination>,
    pub episodes: Vec<EpisodeRecord>,
    pub control_dt: f64,
    pub wall_s: f64,
}

/// Runs the study of `path` on `entry` (a robot with a cell), with `controllers` instead of
/// the study's when given.
pub fn run(entry: &RobotEntry, path: &Path, controllers: &[String]) -> anyhow::Result<CellStudyResult> {
    let started = Instant::now();
    let study = CellStudy::read(path)?;
    let arm = CellArm::of(entry)?;
    if let Some(robot) = &study.robot {
        anyhow::ensure!(
            arm.is(robot, path),
            "{}: robot = '{robot}', but the study runs {}",
            path.display(),
            entry.name
        );
    }
    let base = path.parent().unwrap_or(Path::new("."));
    let layouts =
        study.layouts(base, &arm.default_layout()).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
    let arms = (layouts.iter())
        .map(|(name, l)| arm.placed(l).map_err(|e| anyhow::anyhow!("{}: layout '{name}': {e:#}", path.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let named = open_all(entry, path, &study.controllers, controllers)?;
    let nominal_part =
        CellFurniture::default().part.links.iter().find_map(|l| l.inertial.map(|i| i.mass)).unwrap_or(0.0);
    let combinations = study.combinations(named.len(), layouts.len());
    // Which waypoints of each layout the arm cannot reach.
    let unreachable: Vec<Vec<Stage>> = arms
        .iter()
        .map(|placed| {
            PHASES.iter().map(|(s, _)| *s).filter(|&s| !placed.reachable(waypoint(s, &placed.fixtures))).collect()
        })
        .collect();
    let total = combinations.len() * study.episodes;
    println!(
        "{}: {} combinations × {} episodes = {total} episodes, {} controller(s), {} layout(s)",
        path.display(),
        combinations.len(),
        study.episodes,
        named.len(),
        layouts.len()
    );
    let mut episodes = Vec::new();
    let mut control_dt = 0.0;
    let mut progress = Progress::new(total);
    for (c, controller) in named.iter().enumerate() {
        let mine: Vec<usize> = (0..combinations.len()).filter(|&i| combinations[i].controller == c).collect();
        // The UR5e's cell lays out each arena on its own; a robot file's arm stands in one
        // layout per app.
        let groups: Vec<(Option<usize>, Vec<usize>)> = match &arm {
            CellArm::Ur5e => vec![(None, mine)],
            CellArm::File(_) => (0..layouts.len())
                .map(|l| (Some(l), mine.iter().copied().filter(|&i| combinations[i].layout == l).collect()))
                .collect(),
        };
        for (layout, group) in &groups {
            let batch_entry = match layout {
                Some(l) => arms[*l].entry(entry)?,
                None => entry.clone(),
            };
            for batch in group.chunks(BATCH) {
                let setup = Batch {
                    study: &study,
                    layouts: &layouts,
                    unreachable: &unreachable,
                    combinations: &combinations,
                    members: batch,
                    nominal_part,
                };
                let (records, dt) = setup.run(&batch_entry, controller, &mut progress)?;
                episodes.extend(records);
                control_dt = dt;
            }
        }
    }
    episodes.sort_by_key(|e| (e.combination, e.episode));
    println!("{total} episodes in {:.1} s", started.elapsed().as_secs_f64());
    Ok(CellStudyResult {
        robot: entry.name.to_string(),
        controllers: named.iter().map(|c| c.label.clone()).collect(),
        study,
        layouts,
        arms,
        combinations,
        episodes,
        control_dt,
        wall_s: started.elapsed().as_secs_f64(),
    })
}

/// Episodes finished so far: a bar on a terminal, else a line every 5 s (as training shows
/// its progress).
struct Progress {
    started: Instant,
    total: usize,
    done: usize,
    shown: Instant,
    bar: Option<indicatif::ProgressBar>,
}

impl Progress {
    fn new(total: usize) -> Self {
        use std::io::IsTerminal;
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {pos}/{len} episodes ({eta} left)",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar
        });
        Self { started: Instant::now(), total, done: 0, shown: Instant::now(), bar }
    }

    fn add(&mut self, n: usize) {
        self.done += n;
        if let Some(bar) = &self.bar {
            bar.set_position(self.done as u64);
            if self.done == self.total {
                bar.finish();
            }
        } else if self.shown.elapsed().as_secs_f64() >= 5.0 || self.done == self.total {
            self.shown = Instant::now();
            eprintln!("[{:.0} s] {}/{} episodes", self.started.elapsed().as_secs_f64(), self.done, self.total);
        }
    }
}

/// Combinations of one controller run in one app, an arena each.
struct Batch<'a> {
    study: &'a CellStudy,
    layouts: &'a [(String, CellLayout)],
    unreachable: &'a [Vec<Stage>],
    combinations: &'a [Combination],
    members: &'a [usize],
    nominal_part: f32,
}

/// Where an arena's current episode stands.
#[derive(Default)]
struct Tally {
    done: usize,
    step: u32,
    phases_s: [f64; 9],
    reach_failure: bool,
    queue: VecDeque<Vec<f32>>,
    held: Option<Vec<f32>>,
}

impl Batch<'_> {
    fn run(
        &self,
        entry: &RobotEntry,
        controller: &NamedController,
        progress: &mut Progress,
    ) -> anyhow::Result<(Vec<EpisodeRecord>, f64)> {
        let combos: Vec<&Combination> = self.members.iter().map(|&i| &self.combinations[i]).collect();
        let cell_layouts = CellLayouts(combos.iter().map(|c| self.layouts[c.layout].1.clone()).collect());
        let mut env = controller.env(entry, Some("pick-place"), combos.len(), self.study.seed, |app| {
            // The UR5e's cell reads each arena's layout from it; a robot file's arm was built
            // standing in its batch's one layout.
            app.insert_resource(cell_layouts);
            add_payloads(app);
            Ok(())
        })?;
        let settings = *env.app().world().resource::<SimSettings>();
        let dt = settings.control_seconds();
        let arenas = env.arenas().to_vec();
        let world = env.app_mut().world_mut();
        for (&arena, combo) in arenas.iter().zip(&combos) {
            let parts = arm::cell_parts(world, arena)?;
            world.entity_mut(arena).insert(SpeedSlider(combo.speed));
            if let Some(mass) = combo.payload {
                // The study's payloads are positive: the part keeps a mass.
                world.entity_mut(arena).insert(Payload { link: parts.part, extra_kg: mass as f32 - self.nominal_part });
            }
            if combo.failure == Failure::FailedGrasp
                && let Some(mut gripper) = world.get_mut::<VacuumGripper>(parts.gripper)
            {
                gripper.leaking = true;
            }
        }
        // Every combination meets the same sequence of starts (common random numbers).
        let mut obs = reset_alike(&mut env, &vec![self.study.seed; arenas.len()])?;
        let dim = env.observation_space().dim();
        let action_dim = env.action_space().dim();
        let steps_at = |s: f64| (s / dt).round() as u32;
        let (push_at, dropout) = (
            steps_at(self.study.push.at),
            (steps_at(self.study.dropout.at), steps_at(self.study.dropout.duration).max(1)),
        );
        let mut tallies: Vec<Tally> = (0..arenas.len()).map(|_| Tally::default()).collect();
        let mut records = Vec::new();
        let limit = (self.study.episodes as u64 + 1) * u64::from(EPISODE_STEPS) + 10;
        for _ in 0..limit {
            if tallies.iter().all(|t| t.done >= self.study.episodes) {
                break;
            }
            let mut seen = obs.clone();
            for (i, (t, combo)) in tallies.iter_mut().zip(&combos).enumerate() {
                let row = &mut seen[i * dim..(i + 1) * dim];
                if combo.failure == Failure::SensorDropout && (dropout.0..dropout.0 + dropout.1).contains(&t.step) {
                    row.copy_from_slice(t.held.get_or_insert_with(|| row.to_vec()));
                }
                if t.step == push_at && matches!(combo.failure, Failure::PushTool | Failure::PushPart) {
                    let world = env.app_mut().world_mut();
                    let parts = arm::cell_parts(world, arenas[i])?;
                    let link = if combo.failure == Failure::PushTool { parts.tool } else { parts.part };
                    let push = Push::lasting(
                        Vec3::from(self.study.push.force),
                        Vec3::ZERO,
                        self.study.push.duration as f32,
                        settings.dt,
                    );
                    world.entity_mut(link).insert(push);
                }
            }
            let wanted = controller.act(&seen, dim)?;
            let mut actions = Vec::with_capacity(wanted.len());
            for (i, (t, combo)) in tallies.iter_mut().zip(&combos).enumerate() {
                t.queue.push_back(wanted[i * action_dim..(i + 1) * action_dim].to_vec());
                // Until the first command arrives, the arm holds (zero joint speeds).
                let applied = if t.queue.len() > combo.latency as usize {
                    t.queue.pop_front().expect("non-empty")
                } else {
                    vec![0.0; action_dim]
                };
                actions.extend(applied);
                if let Some(stage) = arm::stage(env.app().world(), arenas[i]) {
                    if let Some(p) = PHASES.iter().position(|(s, _)| *s == stage) {
                        t.phases_s[p] += dt;
                    }
                    t.reach_failure |= self.unreachable[combo.layout].contains(&stage);
                }
            }
            let out = env.step(&actions)?;
            for (i, t) in tallies.iter_mut().enumerate() {
                t.step += 1;
                let Some(summary) = &out.episodes[i] else { continue };
                if t.done < self.study.episodes {
                    records.push(record(self.members[i], t, summary));
                    progress.add(1);
                }
                *t = Tally { done: t.done + 1, ..Tally::default() };
            }
            obs = out.obs;
        }
        anyhow::ensure!(
            tallies.iter().all(|t| t.done >= self.study.episodes),
            "the study's episodes did not end within {limit} control steps"
        );
        Ok((records, dt))
    }
}

fn record(combination: usize, t: &Tally, summary: &EpisodeSummary) -> EpisodeRecord {
    let metric = |name: &str| summary.metrics.get(name).copied().map(f64::from);
    let outcome = summary
        .metrics
        .iter()
        .find(|(k, v)| k.starts_with("outcome_") && **v > 0.5)
        .map_or("unknown", |(k, _)| &k["outcome_".len()..]);
    EpisodeRecord {
        combination,
        episode: t.done,
        success: summary.success == Some(true),
        outcome: outcome.to_string(),
        cycle_time_s: metric("cycle_time_s"),
        energy_j: metric("energy_j").unwrap_or(0.0),
        collision_events: metric("collision_events").unwrap_or(0.0) as u32,
        joint_limit_events: metric("joint_limit_events").unwrap_or(0.0) as u32,
        protective_stops: metric("protective_stops").unwrap_or(0.0) as u32,
        reach_failure: t.reach_failure,
        steps: summary.length,
        phases_s: t.phases_s,
    }
}
