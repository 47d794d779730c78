//! Markers: shapes the cameras see and physics does not, such as a reach's target (on a real
//! cell a coloured ball on a thin stand; Webots' `Solid` without `physics`). The renderer draws
//! them beside the links; nothing collides with them, and a policy knows of one only through
//! a camera.

use bevy::prelude::*;

use crate::rapier::math::Pose;
use crate::urdf::Visual;

/// A marker in the arena its [`crate::InArena`] names: its shape and colour, and where it is in
/// the arena's (physics) frame. Move it by setting `pose`.
#[derive(Component, Clone, Debug)]
pub struct Marker {
    /// Its surface is `marker/<name>` ([`crate::Look::marker_surface`]); visual randomization
    /// leaves markers as they are, so a target keeps the look a camera policy learnt it by.
    pub name: String,
    pub visual: Visual,
    pub pose: Pose,
}
