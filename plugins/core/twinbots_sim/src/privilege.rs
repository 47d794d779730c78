//! The Supervisor's privilege, apart from the Supervisor and the arenas it guards (both use it).

use bevy::prelude::*;

/// The Supervisor's privilege: present in apps that allow it (design patterns 1 and 2, tools
/// and renderers of the true world). It is the only key to an arena's physics world outside
/// the simulator (`Arena::physics`) and to the `Supervisor`. Only `SupervisorPlugin` makes one
/// (the field is private to this crate), so under design pattern 3, whose app has none, no code
/// can read the true world: a system asking for it fails the moment it would first run, naming
/// this resource.
#[derive(Resource, Debug)]
pub struct SupervisorAccess(());

impl SupervisorAccess {
    /// The privilege, for `SupervisorPlugin` to grant.
    pub(crate) fn granted() -> Self {
        Self(())
    }
}
