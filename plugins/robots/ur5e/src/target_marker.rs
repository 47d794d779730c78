//! The reach's target as a camera sees it: a ball on a thin stand, in signal green (no other
//! surface of the cell is green), where the target is, in every arena of the reach. For the
//! camera reach (docs/pixels.md), where only a camera tells the policy where the target is, and
//! for people watching. The stand is what makes the ball's height readable from one camera: a
//! ball alone could be anywhere along its line of sight, a stand's foot on the table top fixes
//! where it is over the table (a real target prop stands so, too). Markers are drawn, never
//! simulated: the arm passes through them.

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{Geometry, Shape, Visual};
use twinbots_sim::{InArena, Marker};

use crate::cell::CellParts;
use crate::reach::TARGET_HEIGHT;
use crate::state::CellState;

/// The ball's radius (m).
pub const BALL_RADIUS: f32 = 0.03;
/// The stand's radius (m) and length: from the ball's centre down past the table top for the
/// highest target (the table hides the rest).
pub const STAND_RADIUS: f32 = 0.012;
const STAND_LENGTH: f32 = TARGET_HEIGHT[1] + 0.05;
const GREEN: [f32; 4] = [0.05, 0.85, 0.1, 1.0];

/// The arena's target marker: its ball and its stand.
#[derive(Component)]
pub struct TargetMarker {
    pub ball: Entity,
    pub stand: Entity,
}

/// Start-up: a marker in each arena (posed by [`place_target_marker`]).
pub fn spawn_target_markers(mut commands: Commands, arenas: Query<Entity, (With<CellParts>, Without<TargetMarker>)>) {
    let visual = |shape| Visual { geometry: Geometry { origin: Pose::IDENTITY, shape }, rgba: GREEN };
    for arena in &arenas {
        let mut marker = |name: &str, shape| {
            commands
                .spawn((Marker { name: name.into(), visual: visual(shape), pose: Pose::IDENTITY }, InArena(arena)))
                .id()
        };
        let ball = marker("target", Shape::Sphere { radius: BALL_RADIUS });
        let stand = marker("target_stand", Shape::Cylinder { radius: STAND_RADIUS, length: STAND_LENGTH });
        commands.entity(arena).insert(TargetMarker { ball, stand });
    }
}

/// The ball at the target (base frame), its stand below it, in the arena's frame.
pub fn place_target_marker(arenas: Query<(&CellParts, &CellState, &TargetMarker)>, mut markers: Query<&mut Marker>) {
    for (parts, state, marker) in &arenas {
        let below = state.target - Vec3::Z * (STAND_LENGTH / 2.0);
        for (entity, at) in [(marker.ball, state.target), (marker.stand, below)] {
            if let Ok(mut m) = markers.get_mut(entity) {
                m.pose = parts.base * Pose::from_translation(at);
            }
        }
    }
}
