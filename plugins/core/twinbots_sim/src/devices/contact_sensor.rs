//! A contact sensor: what the body of the link it is mounted on touches, as a robot's skin or
//! bumpers report it (Webots' TouchSensor of the bumper type, which also says what it hit). A
//! robot counts its collisions from these readings instead of reading the physics world, so a
//! design-pattern-3 robot can count them too.

use std::collections::HashMap;

use bevy::prelude::*;

use super::due::samples_now;
use super::mount::{Mount, SamplingPeriod};
use crate::arena::{Arena, InArena};
use crate::physics::SimClock;
use crate::rapier::prelude::*;
use crate::robot::Link;

/// Something a contact sensor's body touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Touched {
    /// A link of a robot or an object of the cell (a fixture, a part): its entity.
    Link(Entity),
    /// The cell's fixed geometry, which has no link: ground, walls, tables.
    Fixed,
}

/// The contacts of the mount's link body at the last sample: each thing touched once, in the
/// order rapier lists the contacts. Touching means an active contact (the shapes meet), not
/// merely overlapping bounding boxes.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct ContactSensor {
    pub contacts: Vec<Touched>,
}

impl ContactSensor {
    pub fn touching(&self) -> bool {
        !self.contacts.is_empty()
    }

    /// Whether it touches anything but `allowed` (e.g. the part a gripper is meant to hold).
    pub fn touches_other_than(&self, allowed: Touched) -> bool {
        self.contacts.iter().any(|&t| t != allowed)
    }
}

/// For each arena, which link entity stands for each rigid body: the link whose frame is the
/// body's (several links welded by fixed joints share one body; the first of them owns it).
fn body_owners(links: &Query<(Entity, &Link, &InArena)>) -> HashMap<(Entity, RigidBodyHandle), Entity> {
    let mut owners = HashMap::new();
    for (entity, link, in_arena) in links {
        let key = (in_arena.0, link.body);
        if link.offset == Pose::IDENTITY {
            owners.insert(key, entity);
        } else {
            owners.entry(key).or_insert(entity);
        }
    }
    owners
}

pub(crate) fn sample_contact_sensors(
    clock: Res<SimClock>,
    links: Query<(Entity, &Link, &InArena)>,
    arenas: Query<&Arena>,
    mut sensors: Query<(&mut ContactSensor, &Mount, &InArena, Option<&SamplingPeriod>)>,
) {
    let mut owners = None;
    for (mut sensor, mount, in_arena, period) in &mut sensors {
        let Ok(arena) = arenas.get(in_arena.0) else { continue };
        if !samples_now(arena, period, clock.control_steps) {
            continue;
        }
        let Ok((_, link, _)) = links.get(mount.link) else { continue };
        let world = &arena.world;
        let Some(body) = world.bodies.get(link.body) else { continue };
        let owners = owners.get_or_insert_with(|| body_owners(&links));
        let mut contacts = Vec::new();
        for &own in body.colliders() {
            for pair in world.contact_pairs_with(own).filter(|p| p.has_any_active_contact()) {
                let other = if pair.collider1 == own { pair.collider2 } else { pair.collider1 };
                let touched = match world.colliders.get(other).and_then(|c| c.parent()) {
                    Some(other_body) => {
                        owners.get(&(in_arena.0, other_body)).map_or(Touched::Fixed, |&e| Touched::Link(e))
                    }
                    None => Touched::Fixed,
                };
                if !contacts.contains(&touched) {
                    contacts.push(touched);
                }
            }
        }
        sensor.contacts = contacts;
    }
}
