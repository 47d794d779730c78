//! Demonstrations (`twinbots demos`, docs/demos.md): a controller — the task's scripted or
//! classical one, a trained run, an ONNX policy — drives the twin for N episodes, and every
//! control step becomes a frame of a LeRobot dataset (`twinbots_dataset`).
//!
//! With cameras (`--cameras side,iso`), every frame also holds each camera's image of the
//! state it observed, rendered off-screen (every arena in one frame, as pixel observations
//! are) and written as the dataset's image features.
//!
//! Episode `j` starts from seed `seed + j` in whichever arena it runs (arenas start alike from
//! a seed, [`reset_alike`]), so a dataset is the same frame for frame whatever the arena count,
//! and the `seed` column says how to replay any of its episodes.

use std::path::Path;
use std::time::Instant;

use bevy::prelude::Entity;
use twinbots_api::{Space, VecEnv};
use twinbots_dataset::{CameraSpec, DatasetSpec, DatasetWriter, Episode, Frame};
use twinbots_render::{Renderer, View};
use twinbots_task::AppVecEnv;

use crate::controller::{NamedController, reset_alike};
use twinbots_run::registry::RobotEntry;

/// What `twinbots demos` is asked for.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    /// `classic`, a run directory or an `.onnx` file.
    pub controller: String,
    /// The task (`None`: the main one; a run's own task for a run).
    pub task: Option<String>,
    pub episodes: usize,
    /// Episodes run side by side.
    pub arenas: usize,
    /// Episode `j` starts from `seed + j`.
    pub seed: u64,
    /// Keep only episodes that met the task's goal (drawing further seeds until there are
    /// `episodes` of them).
    pub successes_only: bool,
    /// The robot's framed cameras whose images every frame holds (none: state only).
    pub cameras: Vec<String>,
    /// The images' width and height (pixels).
    pub image_size: (u32, u32),
}

/// What was written.
#[derive(Clone, Debug, PartialEq)]
pub struct DemoSummary {
    pub episodes: usize,
    pub frames: usize,
    /// Episodes run (more than `episodes` where only successes were kept).
    pub episodes_run: usize,
    pub successes: usize,
    /// Frames recorded a second of wall-clock time, the dataset's writing included.
    pub frames_per_second: f64,
}

/// Progress after every batch of arenas: episodes kept, episodes run, frames a second so far.
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize, f64);

/// Runs the episodes and writes them as a LeRobot dataset at `out` (a new directory).
pub fn record_demos(
    entry: &RobotEntry,
    options: &DemoOptions,
    out: &Path,
    progress: Progress,
) -> anyhow::Result<DemoSummary> {
    anyhow::ensure!(options.episodes > 0, "--episodes must be at least 1");
    anyhow::ensure!(options.arenas > 0, "--arenas must be at least 1");
    let started = Instant::now();
    let controller = NamedController::open_for(&options.controller, Path::new("."), entry, options.task.as_deref())?;
    // A run drives the task it was trained on unless told another.
    let task = match (&options.task, &controller.controller) {
        (Some(t), _) => Some(t.clone()),
        (None, crate::controller::Controller::Run { settings, .. }) => Some(settings.task_name(entry)?.to_string()),
        (None, _) => None,
    };
    let description = entry.find_task(task.as_deref())?;
    let arenas = options.arenas.min(options.episodes);
    let mut env = controller.env(entry, task.as_deref(), arenas, options.seed, |_| Ok(()))?;
    let spec = env.task().clone();
    // Discrete choices are recorded as twinbots carries them: their index as a float.
    let bounds = match env.action_space() {
        Space::Box { low, high } => Some((low.clone(), high.clone())),
        _ => None,
    };
    anyhow::ensure!(
        matches!(env.observation_space(), Space::Box { .. }),
        "{}'s task '{}' observes images: demos write state observations only (camera streams are not written yet)",
        entry.name,
        description.name
    );
    let (obs_dim, act_dim) = (env.observation_space().dim(), env.action_space().dim());
    let mut cameras = Cameras::new(entry, &options.cameras, options.image_size, arenas)?;
    let mut writer = DatasetWriter::new(
        out,
        DatasetSpec {
            robot: entry.name.to_string(),
            fps: frames_per_second(entry.control_period_s()),
            state_names: spec.observation_names.clone(),
            action_names: (0..act_dim).map(|j| format!("action_{j}")).collect(),
            cameras: cameras.specs(),
        },
    )?;
    let (mut run, mut successes, mut frames) = (0usize, 0usize, 0usize);
    while writer.episodes() < options.episodes {
        // The next batch: one episode per arena, seeds in order.
        let wanted = if options.successes_only { arenas } else { arenas.min(options.episodes - writer.episodes()) };
        let seeds: Vec<u64> = (0..arenas as u64).map(|i| options.seed + (run as u64) + i).collect();
        let mut obs = reset_alike(&mut env, &seeds)?;
        let mut images = cameras.shoot(&mut env)?;
        // Each kept arena's frames, and once its episode has ended whether it succeeded.
        let mut episodes: Vec<Vec<Frame>> = vec![Vec::new(); wanted];
        let mut ended: Vec<Option<bool>> = vec![None; wanted];
        while ended.iter().any(Option::is_none) {
            let mut actions = controller.act(&obs, obs_dim)?;
            if let Some((low, high)) = &bounds {
                for (j, a) in actions.iter_mut().enumerate() {
                    *a = a.clamp(low[j % act_dim], high[j % act_dim]);
                }
            }
            let step = env.step(&actions)?;
            for i in 0..wanted {
                if ended[i].is_some() {
                    continue;
                }
                let done = step.terminated[i] || step.truncated[i];
                let success = done && step.episodes[i].as_ref().and_then(|e| e.success) == Some(true);
                episodes[i].push(Frame {
                    state: obs[i * obs_dim..(i + 1) * obs_dim].to_vec(),
                    action: actions[i * act_dim..(i + 1) * act_dim].to_vec(),
                    reward: step.rewards[i],
                    done,
                    success,
                    images: std::mem::take(&mut images[i]),
                });
                if done {
                    ended[i] = Some(success);
                }
            }
            obs = step.obs;
            images = cameras.shoot(&mut env)?;
        }
        for (i, (episode, success)) in episodes.into_iter().zip(ended).enumerate() {
            let success = success.expect("every episode of the batch ended");
            run += 1;
            successes += usize::from(success);
            if writer.episodes() < options.episodes && (success || !options.successes_only) {
                frames += episode.len();
                writer.add(Episode { task: description.description.to_string(), seed: seeds[i], frames: episode })?;
            }
        }
        progress(writer.episodes(), run, frames as f64 / started.elapsed().as_secs_f64());
    }
    let written = writer.finish()?;
    Ok(DemoSummary {
        episodes: written.episodes,
        frames: written.frames,
        episodes_run: run,
        successes,
        frames_per_second: written.frames as f64 / started.elapsed().as_secs_f64(),
    })
}

/// The cameras a dataset's frames are seen through, and the renderer that shoots them.
struct Cameras {
    renderer: Option<Renderer>,
    /// Name and view of each camera, in the dataset's order.
    views: Vec<(String, View)>,
    size: (u32, u32),
}

impl Cameras {
    /// `names` of the robot's framed cameras, `size` pixels, for `arenas` side by side; no
    /// renderer is made (nor a graphics adapter needed) without cameras.
    fn new(entry: &RobotEntry, names: &[String], size: (u32, u32), arenas: usize) -> anyhow::Result<Self> {
        let views = names
            .iter()
            .map(|name| {
                let view = View::framed(&entry.framing, name).ok_or_else(|| {
                    anyhow::anyhow!("--cameras {name}: {} has no such camera (its cameras: {})", entry.name, {
                        twinbots_sim::Framing::CAMERAS.join(", ")
                    })
                })?;
                Ok((name.clone(), view))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let renderer = match views.is_empty() {
            true => None,
            false => Some(Renderer::tiled(size.0, size.1, arenas)?),
        };
        Ok(Self { renderer, views, size })
    }

    fn specs(&self) -> Vec<CameraSpec> {
        let (width, height) = self.size;
        self.views.iter().map(|(name, _)| CameraSpec { name: name.clone(), width, height }).collect()
    }

    /// Each arena's image through each camera now, as PNGs (per arena, in camera order).
    fn shoot(&mut self, env: &mut AppVecEnv) -> anyhow::Result<Vec<Vec<Vec<u8>>>> {
        let arenas: Vec<Entity> = env.arenas().to_vec();
        let Some(renderer) = self.renderer.as_mut() else { return Ok(vec![Vec::new(); arenas.len()]) };
        let shots: Vec<(Entity, View)> =
            self.views.iter().flat_map(|(_, view)| arenas.iter().map(move |&a| (a, *view))).collect();
        let rgb = renderer.render_shots(env.app_mut().world_mut(), &shots)?;
        let mut out = vec![Vec::with_capacity(self.views.len()); arenas.len()];
        for (k, image) in rgb.iter().enumerate() {
            out[k % arenas.len()].push(png(image, self.size)?);
        }
        Ok(out)
    }
}

fn png(rgb: &[u8], (width, height): (u32, u32)) -> anyhow::Result<Vec<u8>> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out).write_image(rgb, width, height, image::ExtendedColorType::Rgb8)?;
    Ok(out)
}

/// The control rate as LeRobot's `fps`, to a ten-thousandth of a hertz: a period stored as
/// `f32` is off by up to 6e-8 of itself (0.032 s → 31.2499985 Hz), which this rounds away
/// (0.04 s → 25, 0.032 s → 31.25).
fn frames_per_second(period_s: f64) -> f64 {
    (1e4 / period_s).round() / 1e4
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_period_that_makes_a_whole_rate_gives_it() {
        assert_eq!(frames_per_second(f64::from(0.04f32)), 25.0);
        assert_eq!(frames_per_second(f64::from(0.032f32)), 31.25);
    }
}
