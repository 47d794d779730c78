//! The twin's physical parameters by name: what a calibration fits and a truth file sets.
//!
//! Per movable joint `<joint>.damping`, `<joint>.friction`, `<joint>.armature`, per motor
//! `<joint>.gain`, per joint `<joint>.bias` (an encoder offset: the log's readings carry it, the
//! twin's physics does not), and `command_delay` for every motor. SI units. A robot's nominal
//! values come from its URDF (`<dynamics>`) and its plugin; a [`Parameters`] resource in an app
//! overrides them at start-up, before any arena steps or is reset.

use std::collections::BTreeMap;

use bevy::prelude::*;

use crate::arena::{Arena, InArena};
use crate::devices::{Joint, JointDynamics, Motor, set_armature};
use crate::rapier::prelude::PhysicsWorld;
use crate::urdf::RobotModel;

/// What a parameter is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParameterKind {
    Damping,
    Friction,
    Armature,
    Gain,
    Bias,
    CommandDelay,
}

impl ParameterKind {
    fn suffix(self) -> &'static str {
        match self {
            Self::Damping => "damping",
            Self::Friction => "friction",
            Self::Armature => "armature",
            Self::Gain => "gain",
            Self::Bias => "bias",
            Self::CommandDelay => "command_delay",
        }
    }

    /// The parameter of this kind of the joint `joint` (`elbow_joint.damping`).
    pub fn of_joint(self, joint: &str) -> String {
        format!("{joint}.{}", self.suffix())
    }
}

/// One parameter of a robot: its name, its nominal value and its unit.
#[derive(Clone, Debug, PartialEq)]
pub struct ParameterSpec {
    pub name: String,
    pub kind: ParameterKind,
    /// The joint it belongs to (`None` for `command_delay`).
    pub joint: Option<String>,
    pub default: f64,
    pub unit: &'static str,
}

impl ParameterSpec {
    /// The values it may take, in its unit: wide enough for any robot arm or vehicle, narrow
    /// enough that a typo (1e10, a sign) is caught before it reaches the physics.
    pub fn plausible(&self) -> (f64, f64) {
        match self.kind {
            ParameterKind::Damping | ParameterKind::Friction => (0.0, 1e4),
            ParameterKind::Armature => (0.0, 1e3),
            ParameterKind::Gain => (0.01, 100.0),
            ParameterKind::Bias if self.unit == "m" => (-1.0, 1.0),
            ParameterKind::Bias => (-std::f64::consts::PI, std::f64::consts::PI),
            ParameterKind::CommandDelay => (0.0, 1.0),
        }
    }
}

/// Parameter values by name (a calibration's `[parameters]` table), as a resource: applied to
/// every arena's joints at start-up.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct Parameters(pub BTreeMap<String, f64>);

impl Parameters {
    pub fn get(&self, name: &str) -> Option<f64> {
        self.0.get(name).copied()
    }

    /// `other`'s values over these.
    pub fn extend(&mut self, other: &Parameters) {
        self.0.extend(other.0.iter().map(|(k, v)| (k.clone(), *v)));
    }

    /// Every name a parameter of `catalogue` and every value finite and within its kind's
    /// [`ParameterKind::plausible`] range; the error names the first unknown one and lists the
    /// known names, or names the value out of range.
    pub fn check(&self, catalogue: &[ParameterSpec], robot: &str) -> Result<(), String> {
        for (name, value) in &self.0 {
            if !catalogue.iter().any(|p| &p.name == name) {
                let known: Vec<&str> = catalogue.iter().map(|p| p.name.as_str()).collect();
                return Err(format!("unknown parameter '{name}' for robot '{robot}'; known: {}", known.join(", ")));
            }
            if !value.is_finite() {
                return Err(format!("parameter '{name}' is {value}"));
            }
            let spec = catalogue.iter().find(|p| &p.name == name).expect("checked above");
            let (lo, hi) = spec.plausible();
            if !(lo..=hi).contains(value) {
                // 1e300 as such, not as three hundred digits.
                let shown = if value.abs() >= 1e6 { format!("{value:e}") } else { value.to_string() };
                return Err(format!("parameter '{name}' = {shown} {}: outside [{lo}, {hi}]", spec.unit));
            }
        }
        Ok(())
    }
}

/// The parameters of a robot's model, with their nominal values: the URDF's, then `nominal`'s.
pub fn catalogue(model: &RobotModel, nominal: &Parameters) -> Vec<ParameterSpec> {
    let mut out = Vec::new();
    for j in model.joints.iter().filter(|j| j.kind.is_movable()) {
        let rot = j.kind.is_rotational();
        let mut push = |kind: ParameterKind, default: f32, unit_rot: &'static str, unit_lin: &'static str| {
            let name = kind.of_joint(&j.name);
            let default = nominal.get(&name).unwrap_or(default as f64);
            out.push(ParameterSpec {
                name,
                kind,
                joint: Some(j.name.clone()),
                default,
                unit: if rot { unit_rot } else { unit_lin },
            });
        };
        push(ParameterKind::Damping, j.damping, "N*m*s/rad", "N*s/m");
        push(ParameterKind::Friction, j.friction, "N*m", "N");
        push(ParameterKind::Armature, 0.0, "kg*m^2", "kg");
        if j.limits.effort > 0.0 {
            push(ParameterKind::Gain, 1.0, "1", "1");
        }
        push(ParameterKind::Bias, 0.0, "rad", "m");
    }
    let delay = nominal.get("command_delay").unwrap_or(0.0);
    out.push(ParameterSpec {
        name: "command_delay".into(),
        kind: ParameterKind::CommandDelay,
        joint: None,
        default: delay,
        unit: "s",
    });
    out
}

/// Sets one joint's damping, friction, armature, gain and delay from `params` (the names it
/// holds; others stay as they are).
pub fn apply_to_joint(
    world: &mut PhysicsWorld,
    joint: &Joint,
    dynamics: &mut JointDynamics,
    motor: Option<&mut Motor>,
    params: &Parameters,
) {
    let get = |kind: ParameterKind| params.get(&kind.of_joint(&joint.name));
    if let Some(v) = get(ParameterKind::Damping) {
        dynamics.damping = v as f32;
    }
    if let Some(v) = get(ParameterKind::Friction) {
        dynamics.friction = v as f32;
    }
    if let Some(v) = get(ParameterKind::Armature) {
        set_armature(world, joint, dynamics, v as f32);
    }
    if let Some(motor) = motor {
        if let Some(v) = get(ParameterKind::Gain) {
            motor.gain = v as f32;
        }
        if let Some(v) = params.get("command_delay") {
            motor.delay = v as f32;
        }
    }
}

/// Applies the app's [`Parameters`] at start-up (part of [`crate::SimPlugins`]).
pub struct ParametersPlugin;

impl Plugin for ParametersPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(PostStartup, apply_parameters);
    }
}

/// Start-up: the app's [`Parameters`] on every arena's joints, then each arena's state as
/// built and calibrated becomes the one its resets restore.
pub(crate) fn apply_parameters(
    params: Option<Res<Parameters>>,
    mut arenas: Query<&mut Arena>,
    mut joints: Query<(&Joint, &mut JointDynamics, Option<&mut Motor>, &InArena)>,
) {
    let Some(params) = params else { return };
    if params.0.is_empty() {
        return;
    }
    for (joint, mut dynamics, motor, in_arena) in &mut joints {
        if let Ok(mut arena) = arenas.get_mut(in_arena.0) {
            apply_to_joint(&mut arena.world, joint, &mut dynamics, motor.map(|m| m.into_inner()), &params);
        }
    }
    for mut arena in &mut arenas {
        arena.mark_initial();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_out_of_their_kinds_range_are_named() {
        let spec = |name: &str, kind, unit| ParameterSpec { name: name.into(), kind, joint: None, default: 0.0, unit };
        let catalogue = [
            spec("elbow.damping", ParameterKind::Damping, "N*m*s/rad"),
            spec("elbow.bias", ParameterKind::Bias, "rad"),
            spec("command_delay", ParameterKind::CommandDelay, "s"),
        ];
        let check = |name: &str, value: f64| Parameters([(name.to_string(), value)].into()).check(&catalogue, "arm");
        check("elbow.damping", 2.5).unwrap();
        check("elbow.bias", -0.01).unwrap();
        for (name, value, expected) in [
            ("elbow.damping", -1.0, "parameter 'elbow.damping' = -1 N*m*s/rad: outside [0, 10000]"),
            ("elbow.damping", 1e10, "parameter 'elbow.damping' = 1e10 N*m*s/rad: outside"),
            ("elbow.bias", 7.0, "parameter 'elbow.bias' = 7 rad: outside"),
            ("command_delay", 5.0, "parameter 'command_delay' = 5 s: outside [0, 1]"),
            ("elbow.damping", 1e300, "parameter 'elbow.damping' = 1e300 N*m*s/rad: outside [0, 10000]"),
            ("elbow.damping", f64::NAN, "parameter 'elbow.damping' is NaN"),
        ] {
            let err = check(name, value).unwrap_err();
            assert!(err.starts_with(expected), "{err:?} does not start with {expected:?}");
        }
    }
}
