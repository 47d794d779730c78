//! Domain randomization, set in the run's TOML (`[randomization]`).
//!
//! The paper's `d_randomize`: random actions for a random window at each episode start, and
//! random actions injected with a probability during training. Beyond it, physical
//! randomization drawn at every reset: link masses, friction, motor strength; and sensor noise
//! and action latency throughout. Everything is drawn from the arena's random stream, so a seed
//! still fixes the trajectory. (Design pattern 1 and 2 envs; pattern-3 robots run their own.)
//!
//! Centred on a calibration: with `calibration_spread = k`, every reset draws each fitted
//! parameter of the run's calibration (`twinbots identify`'s file) from a normal distribution
//! around its fitted value with k times the fit's standard deviation (its `[spread]` table, the
//! [`FitSpread`] resource), per arena; values that must be positive are clamped at zero, and
//! encoder biases (which the physics does not carry) are left alone.
//!
//! What cameras see: the `[randomization.visual]` table ([`visual`]).

pub mod visual;

use std::collections::VecDeque;

use bevy::prelude::*;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use twinbots_sim::parameters::apply_to_joint;
use twinbots_sim::{
    Arena, InArena, Joint, JointDynamics, Motor, ParameterKind, Parameters, PositionSensor, SimSet, SupervisorAccess,
};

use crate::task::{Action, ActiveTask, EnvReset, ResetSet, Resetting};

/// `[randomization]` in a run's TOML. Ranges are `[low, high]`, drawn uniformly per episode.
#[derive(Resource, Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Randomization {
    /// d_randomize: the first k steps of an episode take random actions, k in this range.
    pub start_window: [u32; 2],
    /// d_randomize: probability that any step's action is replaced by a random one.
    pub action_probability: f32,
    /// Scale of every body's mass (and inertia).
    pub mass_scale: [f32; 2],
    /// Friction coefficient of every collider.
    pub friction: Option<[f32; 2]>,
    /// Fraction of their rated effort that motors deliver.
    pub motor_strength: [f32; 2],
    /// Standard deviation of position-sensor noise (rad or m).
    pub sensor_noise: f32,
    /// Control steps between an action and its effect.
    pub action_latency: u32,
    /// Draw the calibration's fitted parameters around their values with this multiple of the
    /// fit's standard deviation (0: the fitted values as they are). Needs a calibration with a
    /// `[spread]` table.
    pub calibration_spread: f32,
    /// `[randomization.visual]`: surface colours and textures, lights, camera jitter. Off
    /// without the table.
    pub visual: Option<visual::VisualRandomization>,
}

/// A calibration's standard deviation per fitted parameter (its `[spread]` table): what
/// `calibration_spread` scales. Its centre is the app's [`Parameters`].
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct FitSpread(pub Parameters);

impl Default for Randomization {
    fn default() -> Self {
        Self {
            start_window: [0, 0],
            action_probability: 0.0,
            mass_scale: [1.0, 1.0],
            friction: None,
            motor_strength: [1.0, 1.0],
            sensor_noise: 0.0,
            action_latency: 0,
            calibration_spread: 0.0,
            visual: None,
        }
    }
}

impl Randomization {
    pub fn is_off(&self) -> bool {
        self == &Self::default()
    }

    /// A clear error for ranges that are backwards or out of bounds.
    pub fn validate(&self) -> anyhow::Result<()> {
        // Upper bounds: beyond them the physics is no longer a robot's (and rapier may fail).
        let ordered = |name: &str, [lo, hi]: [f32; 2], min: f32, max: f32| {
            anyhow::ensure!(
                lo.is_finite() && hi.is_finite() && lo <= hi && lo >= min && hi <= max,
                "randomization.{name} = [{lo}, {hi}]: must be finite, ordered and in [{min}, {max}]"
            );
            Ok(())
        };
        let [first, last] = self.start_window;
        anyhow::ensure!(
            first <= last && last <= 100_000,
            "randomization.start_window = [{first}, {last}]: must be ordered and at most 100000 steps"
        );
        anyhow::ensure!(
            self.action_latency <= 1000,
            "randomization.action_latency = {}: must be at most 1000 control steps",
            self.action_latency
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&self.action_probability),
            "randomization.action_probability = {}: must be in [0, 1]",
            self.action_probability
        );
        ordered("mass_scale", self.mass_scale, 1e-3, 1e3)?;
        ordered("motor_strength", self.motor_strength, 0.0, 100.0)?;
        if let Some(f) = self.friction {
            ordered("friction", f, 0.0, 100.0)?;
        }
        anyhow::ensure!(
            self.sensor_noise.is_finite() && (0.0..=1e3).contains(&self.sensor_noise),
            "randomization.sensor_noise = {}: must be a finite number in [0, 1000]",
            self.sensor_noise
        );
        anyhow::ensure!(
            self.calibration_spread.is_finite() && (0.0..=100.0).contains(&self.calibration_spread),
            "randomization.calibration_spread = {}: must be a finite multiple of the fit's standard deviation in [0, 100]",
            self.calibration_spread
        );
        if let Some(v) = &self.visual {
            v.validate()?;
        }
        Ok(())
    }

    /// The `[randomization]` table of a run's TOML `text` (other tables ignored; none: off),
    /// validated.
    pub fn from_config(text: &str) -> anyhow::Result<Self> {
        let table: toml::Table = toml::from_str(text).map_err(|e| anyhow::anyhow!("config is not valid TOML: {e}"))?;
        let Some(section) = table.get("randomization") else { return Ok(Self::default()) };
        let r: Self = section.clone().try_into().map_err(|e| anyhow::anyhow!("config [randomization]: {e}"))?;
        r.validate()?;
        Ok(r)
    }

    /// The `[randomization.visual]` table of a TOML file (a looks file such as
    /// `assets/looks/held-out.toml`); errors name the file.
    pub fn looks_of(file: &std::path::Path) -> anyhow::Result<visual::VisualRandomization> {
        let text = std::fs::read_to_string(file).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
        let randomization = Self::from_config(&text).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
        randomization.visual.ok_or_else(|| anyhow::anyhow!("{}: has no [randomization.visual] table", file.display()))
    }

    /// A clear error when `calibration_spread` is asked for without a spread to scale
    /// (`has_spread`: the run's calibration has a non-empty `[spread]`).
    pub fn check_spread(&self, has_spread: bool) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.calibration_spread == 0.0 || has_spread,
            "randomization.calibration_spread = {} needs a calibration with a [spread] table \
             (`--calibration FILE`; `twinbots identify` writes one)",
            self.calibration_spread
        );
        Ok(())
    }
}

/// Per-arena state: steps of random start left, and actions waiting out the latency.
#[derive(Component, Default)]
struct RandomizationState {
    random_steps_left: u32,
    pending: VecDeque<Vec<f32>>,
}

pub struct RandomizationPlugin(pub Randomization);

impl Plugin for RandomizationPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(self.0.clone())
            .add_systems(PostStartup, (add_state, set_sensor_noise))
            // Actions are replaced or delayed before anything applies them, or radios them to a
            // slave robot (design pattern 2).
            .add_systems(Update, randomize_actions.in_set(SimSet::ProcessActions))
            .add_systems(EnvReset, (randomize_episode, draw_calibration).chain().in_set(ResetSet::Place));
        if let Some(v) = &self.0.visual {
            app.add_plugins(visual::VisualRandomizationPlugin(v.clone()));
        }
    }
}

fn uniform(rng: &mut impl Rng, [lo, hi]: [f32; 2]) -> f32 {
    if hi > lo { rng.random_range(lo..=hi) } else { lo }
}

/// A count drawn uniformly in `[lo, hi]` (no draw when the range is one value).
fn uniform_count(rng: &mut impl Rng, [lo, hi]: [u32; 2]) -> u32 {
    if hi > lo { rng.random_range(lo..=hi) } else { lo }
}

fn add_state(mut commands: Commands, arenas: Query<Entity, With<Arena>>) {
    for arena in &arenas {
        commands.entity(arena).insert(RandomizationState::default());
    }
}

fn set_sensor_noise(config: Res<Randomization>, mut sensors: Query<&mut PositionSensor>) {
    for mut s in &mut sensors {
        s.noise = config.sensor_noise;
    }
}

/// At every reset: masses, friction and motor strength for the new episode, and its random
/// start window.
fn randomize_episode(
    config: Res<Randomization>,
    privilege: Res<SupervisorAccess>,
    mut arenas: Query<(Entity, &mut Arena, Option<&mut RandomizationState>), With<Resetting>>,
    mut motors: Query<(&mut Motor, &InArena)>,
) {
    for (entity, mut arena, state) in &mut arenas {
        let arena = &mut *arena;
        let mass = uniform(&mut arena.rng, config.mass_scale);
        let friction = config.friction.map(|f| uniform(&mut arena.rng, f));
        let strength = uniform(&mut arena.rng, config.motor_strength);
        let random_steps = uniform_count(&mut arena.rng, config.start_window);
        if mass != 1.0 {
            use twinbots_sim::rapier::dynamics::RigidBodyAdditionalMassProps as Extra;
            for (_, body) in arena.physics_mut(&privilege).bodies.iter_mut() {
                // Links carry their URDF inertials as "additional" mass properties (their
                // colliders have no density), restored to nominal by every reset.
                let extra = body.mass_properties().additional_local_mprops.as_deref().cloned();
                if let Some(Extra::MassProps(mut props)) = extra {
                    props.set_mass(props.mass() * mass, true);
                    body.set_additional_mass_properties(props, true);
                }
            }
        }
        if let Some(f) = friction {
            for (_, collider) in arena.physics_mut(&privilege).colliders.iter_mut() {
                collider.set_friction(f);
            }
        }
        for (mut motor, in_arena) in &mut motors {
            if in_arena.0 == entity {
                motor.strength = strength;
            }
        }
        if let Some(mut state) = state {
            state.random_steps_left = random_steps;
            state.pending.clear();
        }
    }
}

/// At every reset, with `calibration_spread`: the fitted parameters drawn around the fit, in
/// the spread's (name) order, per arena.
fn draw_calibration(
    config: Res<Randomization>,
    privilege: Res<SupervisorAccess>,
    centre: Option<Res<Parameters>>,
    spread: Option<Res<FitSpread>>,
    mut arenas: Query<(Entity, &mut Arena), With<Resetting>>,
    mut joints: Query<(&Joint, &mut JointDynamics, Option<&mut Motor>, &InArena)>,
) {
    let (Some(centre), Some(spread)) = (centre, spread) else { return };
    if config.calibration_spread == 0.0 {
        return;
    }
    let k = config.calibration_spread as f64;
    for (entity, mut arena) in &mut arenas {
        let arena = &mut *arena;
        let mut drawn = Parameters::default();
        for (name, sigma) in spread.0.0.iter().filter(|(name, _)| !name.ends_with(".bias")) {
            let Some(value) = centre.get(name) else { continue };
            let z: f64 = StandardNormal.sample(&mut arena.rng);
            drawn.0.insert(name.clone(), (value + k * sigma * z).max(0.0));
        }
        for (joint, mut dynamics, motor, in_arena) in &mut joints {
            if in_arena.0 != entity {
                continue;
            }
            // The restored world carries the fitted armature: a new one is added relative to it.
            if let Some(fitted) = centre.get(&ParameterKind::Armature.of_joint(&joint.name)) {
                dynamics.armature_restored(fitted as f32);
            }
            apply_to_joint(arena.physics_mut(&privilege), joint, &mut dynamics, motor.map(|m| m.into_inner()), &drawn);
        }
    }
}

/// d_randomize on actions, then latency: what the task applies this step.
fn randomize_actions(
    config: Res<Randomization>,
    spec: Res<ActiveTask>,
    mut arenas: Query<(&mut Arena, &mut Action, &mut RandomizationState)>,
) {
    for (mut arena, mut action, mut state) in &mut arenas {
        let random = if state.random_steps_left > 0 {
            state.random_steps_left -= 1;
            true
        } else {
            config.action_probability > 0.0 && arena.rng.random::<f32>() < config.action_probability
        };
        if random {
            action.0 = spec.action_space.sample(&mut arena.rng);
        }
        if config.action_latency > 0 {
            state.pending.push_back(action.0.clone());
            if state.pending.len() > config.action_latency as usize {
                action.0 = state.pending.pop_front().unwrap_or_default();
            } else {
                // Until the first action arrives, the previous command stands (no new action).
                action.0 = state.pending.front().cloned().unwrap_or_default();
                action.0.clear();
            }
        }
    }
}
