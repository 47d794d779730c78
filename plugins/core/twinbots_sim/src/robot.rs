//! What a spawned robot is made of in the world: the [`Robot`] entity and its [`Link`]s (rigid
//! bodies, with what they look like); devices mount on links.

use bevy::prelude::*;

use crate::rapier::prelude::*;

/// A robot in an arena.
#[derive(Component, Clone, Debug)]
pub struct Robot {
    pub name: String,
}

/// A link of a robot. Links welded by fixed joints share one rigid body.
#[derive(Component, Clone, Debug)]
pub struct Link {
    pub name: String,
    pub robot: Entity,
    pub body: RigidBodyHandle,
    /// The link frame in its body's frame.
    pub offset: Pose,
}

/// What a link looks like (its URDF visuals, in the link frame): read by the renderer.
#[derive(Component, Clone, Debug, Default)]
pub struct Visuals(pub Vec<crate::urdf::Visual>);
