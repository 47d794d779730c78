//! `Arenas`: N arenas of one robot task in one Bevy app, stepped together in Rust. This is the
//! engine under `twinbots.make_vec` (Gymnasium), the single envs and the SB3 adapter.

use numpy::ndarray::ArrayD;
use numpy::{IntoPyArray, PyArray1, PyArray3, PyArray4};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use twinbots_api::{DesignPattern, Space, StepResult, TaskSpec, VecEnv};
use twinbots_render::{PixelSettings, Renderer, View};
use twinbots_run::settings::CalibrationSetting;
use twinbots_task::randomization::{Randomization, RandomizationPlugin};
use twinbots_task::{AppVecEnv, RobotDescription};

use crate::actions::{action_values, check_and_clip};
use crate::convert::{OnThisThread, episode_dict, no_panic, runtime_error, space_dict, task_dict, value_error};
use crate::frames::Frames;

#[pyclass(unsendable, module = "twinbots._native")]
pub struct Arenas {
    /// `None` once closed.
    env: Option<AppVecEnv>,
    robot: RobotDescription,
    spec: TaskSpec,
    num_envs: usize,
    pattern: u8,
    frames: Option<Frames>,
}

impl Arenas {
    /// The env and its renderer, or why there is none.
    fn rendering(&mut self) -> PyResult<(&mut AppVecEnv, &mut Frames)> {
        let env = self.env.as_mut().ok_or_else(|| pyo3::exceptions::PyRuntimeError::new_err("this env is closed"))?;
        let frames = self.frames.as_mut().ok_or_else(|| {
            pyo3::exceptions::PyRuntimeError::new_err("rendering is off: create the env with render_mode=\"rgb_array\"")
        })?;
        Ok((env, frames))
    }

    fn env(&mut self) -> PyResult<&mut AppVecEnv> {
        self.env
            .as_mut()
            .ok_or_else(|| pyo3::exceptions::PyRuntimeError::new_err("this env is closed (close() was called)"))
    }

    /// Runs `f` on the app with the GIL released; a panic closes the env (its world may be
    /// half-updated) and comes back as an error.
    fn run_detached<T: Send>(
        &mut self,
        py: Python<'_>,
        what: &str,
        f: impl FnOnce(&mut AppVecEnv) -> anyhow::Result<T> + Send,
    ) -> PyResult<T> {
        let env = OnThisThread(self.env()?);
        let result = py.detach(move || {
            let env = env;
            no_panic(what, || f(env.0))
        });
        if result.is_err() {
            self.env = None;
        }
        result.map_err(runtime_error)
    }
}

#[pymethods]
impl Arenas {
    /// `Arenas(robot, num_envs, seed=0, task=None, pattern=1, config=None, calibration=None,
    /// log=None, pixels=None)`: `task` None is the robot's main task; `config` is TOML text whose
    /// `[randomization]` table applies; `calibration` a calibration file (`twinbots identify`'s)
    /// the twin runs with; `log` a robot log file (.mcap or .csv) that holds arena 0's latest
    /// episode (the running one is added by `close()`); `pixels` the TOML text of a `[pixels]`
    /// table's keys (camera, more_cameras, fov, width, height, frames, state; docs/pixels.md):
    /// the envs observe camera images.
    #[new]
    #[pyo3(signature = (robot, num_envs, seed=0, task=None, pattern=1, config=None, calibration=None, log=None, pixels=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        robot: &str,
        num_envs: usize,
        seed: u64,
        task: Option<&str>,
        pattern: u8,
        config: Option<&str>,
        calibration: Option<std::path::PathBuf>,
        log: Option<std::path::PathBuf>,
        pixels: Option<&str>,
    ) -> PyResult<Self> {
        let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
        if num_envs == 0 {
            return Err(value_error(anyhow::anyhow!("num_envs must be at least 1")));
        }
        let design = match DesignPattern::from_number(pattern) {
            Some(p @ (DesignPattern::Supervised | DesignPattern::Radio)) => p,
            _ => {
                return Err(value_error(anyhow::anyhow!(
                    "pattern must be 1 (Supervisor) or 2 (radio), got {pattern}; pattern 3 runs a real robot's process against `twinbots serve`"
                )));
            }
        };
        let randomization = config.map(Randomization::from_config).transpose().map_err(value_error)?;
        let twin =
            twinbots_run::twin::Twin::of_files(&entry, calibration.as_deref(), log.as_deref()).map_err(value_error)?;
        if let Some(r) = &randomization {
            CalibrationSetting::check_randomization(twin.calibration.as_ref(), r).map_err(value_error)?;
        }
        let pixels: Option<PixelSettings> = pixels
            .map(|text| toml::from_str(text).map_err(|e| anyhow::anyhow!("pixels: {}", e.message())))
            .transpose()
            .map_err(value_error)?;
        if let Some(p) = &pixels {
            p.validate().map_err(value_error)?;
        }
        let mut app = entry.app(task, num_envs, seed, design).map_err(value_error)?;
        twin.configure(&mut app, &entry).map_err(value_error)?;
        if let Some(p) = &pixels {
            // Bad settings are the caller's (ValueError); a missing adapter the machine's.
            p.check(&app).map_err(value_error)?;
            p.install(&mut app, &entry.framing, num_envs).map_err(runtime_error)?;
        }
        if let Some(r) = randomization.filter(|r| !r.is_off()) {
            app.add_plugins(RandomizationPlugin(r));
        }
        let env = no_panic("building the arenas", || Ok(AppVecEnv::new(app))).map_err(runtime_error)?;
        let spec = env.task().clone();
        Ok(Self { env: Some(env), robot: entry, spec, num_envs, pattern, frames: None })
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.num_envs
    }

    #[getter]
    fn robot(&self) -> &'static str {
        self.robot.name
    }

    #[getter]
    fn pattern(&self) -> u8 {
        self.pattern
    }

    /// The task: name, spaces, observation names, reward terms, solved criterion.
    #[getter]
    fn task<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        task_dict(py, &self.spec)
    }

    #[getter]
    fn observation_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, &self.spec.observation_space)
    }

    #[getter]
    fn action_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, &self.spec.action_space)
    }

    /// Seconds of simulated time per step.
    #[getter]
    fn control_dt(&mut self) -> PyResult<f32> {
        let env = self.env()?;
        Ok(env.app().world().resource::<twinbots_sim::SimSettings>().control_dt())
    }

    #[getter]
    fn closed(&self) -> bool {
        self.env.is_none()
    }

    /// Resets every arena (re-seeding their streams if `seed` is given: arena i gets stream i
    /// of the seed) and returns the observations, shape `(num_envs, obs_dim)`.
    #[pyo3(signature = (seed=None))]
    fn reset<'py>(&mut self, py: Python<'py>, seed: Option<u64>) -> PyResult<Bound<'py, PyAny>> {
        let obs = self.run_detached(py, "reset", move |env| env.reset(seed))?;
        self.observations(py, obs)
    }

    /// Applies `actions` (`num_envs × action_dim` values, row-major, in a float32, float64,
    /// int64 or int32 array of any shape; NaN, infinities and invalid
    /// choices raise `ValueError`, boxes are clipped) and advances one control step. Envs flagged in `restart` only begin their
    /// next episode: they are reset after the step, so the action they got has no effect
    /// (Gymnasium's NEXT_STEP autoreset). Returns `(obs, rewards, terminated, truncated,
    /// ended)`, `ended` a list of `(env, final_obs, episode)` for episodes that ended; with
    /// `infos=True`, the fifth is instead the step's infos in Gymnasium's vector layout,
    /// SAME_STEP's `final_obs` and `final_info` included (`_native.vector_infos`), or None when
    /// no episode ended.
    #[pyo3(signature = (actions, restart=None, infos=false))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions: &Bound<'py, PyAny>,
        restart: Option<Vec<usize>>,
        infos: bool,
    ) -> PyResult<Bound<'py, PyTuple>> {
        let mut actions = action_values(actions)?;
        let dim = self.spec.action_space.dim();
        if actions.len() != self.num_envs * dim {
            return Err(value_error(anyhow::anyhow!(
                "got {} action values, expected {} envs × {dim}",
                actions.len(),
                self.num_envs
            )));
        }
        check_and_clip(&self.spec.action_space, &mut actions).map_err(value_error)?;
        let restart = restart.unwrap_or_default();
        if let Some(&i) = restart.iter().find(|&&i| i >= self.num_envs) {
            return Err(value_error(anyhow::anyhow!("restart: env {i} does not exist ({} envs)", self.num_envs)));
        }
        let result = self.run_detached(py, "step", move |env| {
            let mut r = env.step(&actions)?;
            if !restart.is_empty() {
                restart_after_step(env, &restart, &mut r);
            }
            Ok(r)
        })?;
        self.step_tuple(py, result, infos)
    }

    /// Frees the app (and the renderer); any later call raises `RuntimeError`.
    /// Closes the arenas; with a `log`, arena 0's running episode is written first (an error
    /// writing it is raised, after closing).
    fn close(&mut self) -> PyResult<()> {
        let logged = self.env.as_mut().map(|env| twinbots_run::robot_log::finish_log(env.app_mut().world_mut()));
        self.env = None;
        self.frames = None;
        logged.transpose().map(|_| ()).map_err(runtime_error)
    }

    /// Prepares off-screen rendering of arena 0 (`camera`: "iso", "front", "side", "top").
    /// Raises `RuntimeError` when this machine has no graphics adapter.
    #[pyo3(signature = (width=640, height=480, camera="iso"))]
    fn enable_rendering(&mut self, width: u32, height: u32, camera: &str) -> PyResult<()> {
        let view = View::framed(&self.robot.framing, camera).ok_or_else(|| {
            value_error(anyhow::anyhow!(
                "unknown camera '{camera}'; cameras: {}",
                twinbots_render::Framing::CAMERAS.join(", ")
            ))
        })?;
        if width == 0 || height == 0 || width > 4096 || height > 4096 {
            return Err(value_error(anyhow::anyhow!(
                "image size must be between 1x1 and 4096x4096, got {width}x{height}"
            )));
        }
        let renderer =
            no_panic("creating the renderer", || Ok(Renderer::new(width, height)?)).map_err(runtime_error)?;
        self.frames = Some(Frames::new(renderer, view));
        Ok(())
    }

    /// Arena 0 as it is now: an RGB image, shape `(height, width, 3)`, uint8.
    fn render<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<u8>>> {
        let (env, frames) = self.rendering()?;
        let image = no_panic("rendering", || frames.render(env)).map_err(runtime_error)?;
        Ok(image.into_pyarray(py))
    }

    /// Every arena as it is now, drawn in one frame: shape `(num_envs, height, width, 3)`, uint8.
    fn render_all<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray4<u8>>> {
        let (env, frames) = self.rendering()?;
        let images = no_panic("rendering", || frames.render_all(env)).map_err(runtime_error)?;
        Ok(images.into_pyarray(py))
    }
}

/// The restarted envs' step is discarded: they are reset again (a fresh start, not stepped),
/// and report a zero reward and no ending.
fn restart_after_step(env: &mut AppVecEnv, restart: &[usize], r: &mut StepResult) {
    let arenas: Vec<_> = restart.iter().map(|&i| env.arenas()[i]).collect();
    let all = env.arenas().to_vec();
    let world = env.app_mut().world_mut();
    twinbots_task::task::reset(world, &arenas);
    r.obs = twinbots_task::task::observations(world, &all);
    for &i in restart {
        r.rewards[i] = 0.0;
        r.terminated[i] = false;
        r.truncated[i] = false;
        r.final_obs[i] = None;
        r.episodes[i] = None;
    }
}

impl Arenas {
    /// Flat observations as a `(num_envs, obs_dim)` float32 array that owns the Rust buffer (no
    /// copy); camera images as `(num_envs, height, width, channels)` uint8.
    fn observations<'py>(&self, py: Python<'py>, obs: Vec<f32>) -> PyResult<Bound<'py, PyAny>> {
        self.array(py, obs, &[self.num_envs])
    }

    /// One env's observation: flat float32, or a `(height, width, channels)` uint8 image.
    fn observation<'py>(&self, py: Python<'py>, obs: Vec<f32>) -> PyResult<Bound<'py, PyAny>> {
        self.array(py, obs, &[])
    }

    /// Observations shaped `batch` × one observation's shape: float32 rows, or uint8 images
    /// (their values are whole numbers 0–255: the cast is exact).
    fn array<'py>(&self, py: Python<'py>, obs: Vec<f32>, batch: &[usize]) -> PyResult<Bound<'py, PyAny>> {
        let wrong = |e: numpy::ndarray::ShapeError| {
            runtime_error(anyhow::anyhow!("observation of the wrong size from the simulation: {e}"))
        };
        let shape = |one: &[usize]| [batch, one].concat();
        Ok(match self.spec.observation_space {
            Space::Image { height, width, channels } => {
                let bytes: Vec<u8> = obs.iter().map(|&v| v as u8).collect();
                ArrayD::from_shape_vec(shape(&[height, width, channels]), bytes)
                    .map_err(wrong)?
                    .into_pyarray(py)
                    .into_any()
            }
            // Gymnasium's Dict: {"image": uint8 images, "state": float32 rows}.
            Space::ImageAndState { height, width, channels, ref low, .. } => {
                let (pixels, state) = (height * width * channels, low.len());
                let (mut bytes, mut values) =
                    (Vec::with_capacity(obs.len()), Vec::with_capacity(obs.len() / pixels.max(1) * state));
                for row in obs.chunks(pixels + state) {
                    let (image, rest) = row.split_at(pixels.min(row.len()));
                    bytes.extend(image.iter().map(|&v| v as u8));
                    values.extend_from_slice(rest);
                }
                let d = PyDict::new(py);
                d.set_item(
                    "image",
                    ArrayD::from_shape_vec(shape(&[height, width, channels]), bytes).map_err(wrong)?.into_pyarray(py),
                )?;
                d.set_item("state", ArrayD::from_shape_vec(shape(&[state]), values).map_err(wrong)?.into_pyarray(py))?;
                d.into_any()
            }
            ref space => ArrayD::from_shape_vec(shape(&[space.dim()]), obs).map_err(wrong)?.into_pyarray(py).into_any(),
        })
    }

    /// `(obs, rewards, terminated, truncated, ended)`; with `infos`, the fifth is the step's
    /// infos in Gymnasium's vector layout with SAME_STEP's `final_obs` (`infos::build`), or None
    /// when no episode ended.
    fn step_tuple<'py>(&self, py: Python<'py>, r: StepResult, infos: bool) -> PyResult<Bound<'py, PyTuple>> {
        let mut ended = Vec::new();
        for (i, (final_obs, episode)) in r.final_obs.into_iter().zip(r.episodes).enumerate() {
            if let (Some(final_obs), Some(episode)) = (final_obs, episode) {
                ended.push((i, self.observation(py, final_obs)?, episode));
            }
        }
        let ended = if !infos {
            let list = PyList::empty(py);
            for (i, obs, episode) in &ended {
                list.append((*i, obs, episode_dict(py, episode)?))?;
            }
            list.into_any()
        } else if ended.is_empty() {
            py.None().into_bound(py)
        } else {
            let ended: Vec<_> =
                ended.into_iter().map(|(i, obs, episode)| (i, obs, crate::infos::Summary::from(&episode))).collect();
            crate::infos::build(py, self.num_envs, &ended, true)?.into_any()
        };
        let obs = self.observations(py, r.obs)?;
        let rewards: Bound<'py, PyArray1<f32>> = r.rewards.into_pyarray(py);
        let terminated: Bound<'py, PyArray1<bool>> = r.terminated.into_pyarray(py);
        let truncated: Bound<'py, PyArray1<bool>> = r.truncated.into_pyarray(py);
        PyTuple::new(py, [obs, rewards.into_any(), terminated.into_any(), truncated.into_any(), ended])
    }
}
