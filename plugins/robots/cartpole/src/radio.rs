//! Design pattern 2 for the cart-pole: SupervisorRobot + SlaveRobot over radio.
//!
//! The slave (the cart-pole) has only its sensors, motors, an Emitter and a Receiver: every step
//! it sends its pole-angle and wheel-encoder readings, and it drives its wheels with the last
//! action it received. The supervisor robot, a massless "PC" welded beside the cell, receives
//! the readings, adds privileged data (the cart's x and velocity, the pole's angular velocity),
//! hands the observation to the model, and radios the model's action back. Radio delivery takes
//! one control step each way, so the model sees readings one step old and its action acts one
//! step late.

use std::path::Path;

use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::parse_urdf;
use twinbots_sim::{
    Arena, Emitter, InArena, Motor, Mount, PositionSensor, Receiver, SimSet, SpawnOptions, Supervisor, spawn_robot,
};
use twinbots_task::Action;
use twinbots_task::task::{EnvReset, ResetSet, Resetting, TaskSet};

use crate::{CartPoleParts, CartPoleState, drive_wheels};

/// Channel the slave sends readings on.
pub const READINGS_CHANNEL: i32 = 1;
/// Channel the supervisor sends actions on.
pub const ACTIONS_CHANNEL: i32 = 2;

const SUPERVISOR_ROBOT: &str = r#"<robot name="supervisor"><link name="world"/></robot>"#;

/// The radios of an arena, kept on the arena entity.
#[derive(Component, Clone, Copy, Debug)]
pub struct RadioLink {
    pub slave_emitter: Entity,
    pub slave_receiver: Entity,
    pub supervisor_emitter: Entity,
    pub supervisor_receiver: Entity,
}

/// The supervisor's latest readings from the slave: pole angle and wheel encoder (rad).
#[derive(Component, Clone, Copy, Debug, Default)]
struct LastReadings(Option<[f32; 2]>);

pub(crate) fn equip(commands: &mut Commands, arena_entity: Entity, arena: &mut Arena, parts: &CartPoleParts) {
    let on = |link: Entity| (Mount { link, offset: Pose::IDENTITY }, InArena(arena_entity));
    let slave_emitter = commands.spawn((Emitter::new(READINGS_CHANNEL), on(parts.cart))).id();
    let slave_receiver = commands.spawn((Receiver::new(ACTIONS_CHANNEL), on(parts.cart))).id();
    let model = parse_urdf(SUPERVISOR_ROBOT, Path::new("supervisor.urdf"), Path::new("."))
        .expect("the supervisor robot's URDF is valid");
    let pc = spawn_robot(
        commands,
        arena_entity,
        arena,
        &model,
        SpawnOptions { base: Pose::from_translation(Vec3::new(0.0, 1.0, 0.5)), fixed_base: true, ..default() },
    );
    let pc = pc.link("world").expect("the supervisor robot has its link");
    let supervisor_emitter = commands.spawn((Emitter::new(ACTIONS_CHANNEL), on(pc))).id();
    let supervisor_receiver = commands.spawn((Receiver::new(READINGS_CHANNEL), on(pc))).id();
    commands.entity(arena_entity).insert((
        RadioLink { slave_emitter, slave_receiver, supervisor_emitter, supervisor_receiver },
        LastReadings::default(),
    ));
}

pub(crate) fn build(app: &mut App) {
    app.add_systems(
        Update,
        (
            (supervisor_sends_action, slave_applies_action).in_set(SimSet::Actuate),
            slave_sends_readings.in_set(SimSet::Task).before(TaskSet::Read),
            supervisor_reads.in_set(TaskSet::Read),
        ),
    )
    .add_systems(EnvReset, (clear_radio.in_set(ResetSet::Place), supervisor_reads.in_set(ResetSet::Read)));
}

// --- the slave robot: sensors, motors, radio; nothing privileged ---

fn slave_applies_action(
    arenas: Query<(&CartPoleParts, &RadioLink)>,
    mut receivers: Query<&mut Receiver>,
    mut motors: Query<&mut Motor>,
) {
    for (parts, radio) in &arenas {
        let Ok(mut rx) = receivers.get_mut(radio.slave_receiver) else { continue };
        let mut latest = None;
        while let Some(packet) = rx.next_packet() {
            latest = packet.data.first().copied();
        }
        if let Some(action) = latest {
            drive_wheels(parts, action as f32, &mut motors);
        }
    }
}

fn slave_sends_readings(
    arenas: Query<(&CartPoleParts, &RadioLink)>,
    sensors: Query<&PositionSensor>,
    mut emitters: Query<&mut Emitter>,
) {
    for (parts, radio) in &arenas {
        let read = |e: Entity| sensors.get(e).map_or(0.0, |s| s.value);
        let mut packet = read(parts.pole_joint).to_le_bytes().to_vec();
        packet.extend(read(parts.wheels[0]).to_le_bytes());
        if let Ok(mut tx) = emitters.get_mut(radio.slave_emitter) {
            tx.send(packet);
        }
    }
}

// --- the supervisor robot: radio plus privileged access ---

fn supervisor_sends_action(arenas: Query<(&Action, &RadioLink)>, mut emitters: Query<&mut Emitter>) {
    for (action, radio) in &arenas {
        if let (Some(&a), Ok(mut tx)) = (action.0.first(), emitters.get_mut(radio.supervisor_emitter)) {
            tx.send(vec![(a >= 0.5) as u8]);
        }
    }
}

fn supervisor_reads(
    supervisor: Supervisor,
    mut arenas: Query<(&CartPoleParts, &RadioLink, &mut LastReadings, &mut CartPoleState)>,
    mut receivers: Query<&mut Receiver>,
) {
    for (parts, radio, mut last, mut state) in &mut arenas {
        if let Ok(mut rx) = receivers.get_mut(radio.supervisor_receiver) {
            while let Some(packet) = rx.next_packet() {
                if let [a0, a1, a2, a3, w0, w1, w2, w3] = packet.data[..] {
                    last.0 = Some([f32::from_le_bytes([a0, a1, a2, a3]), f32::from_le_bytes([w0, w1, w2, w3])]);
                }
            }
        }
        let (Some(cart), Some(pole)) = (supervisor.link_state(parts.cart), supervisor.link_state(parts.pole_link))
        else {
            continue;
        };
        // Right after a reset no readings have arrived yet: the supervisor looks for itself.
        state.angle = match last.0 {
            Some([angle, _]) => angle,
            None => supervisor.joint_position(parts.pole_joint).unwrap_or(0.0),
        };
        state.x = cart.pose.translation.x;
        state.v = cart.linvel.x;
        state.rate = pole.angvel.y;
    }
}

/// A reset arena starts with empty queues: nothing from the last episode is in the air.
fn clear_radio(
    mut arenas: Query<(&RadioLink, &mut LastReadings), With<Resetting>>,
    mut receivers: Query<&mut Receiver>,
    mut emitters: Query<&mut Emitter>,
) {
    for (radio, mut last) in &mut arenas {
        last.0 = None;
        for rx in [radio.slave_receiver, radio.supervisor_receiver] {
            if let Ok(mut rx) = receivers.get_mut(rx) {
                rx.clear();
            }
        }
        for tx in [radio.slave_emitter, radio.supervisor_emitter] {
            if let Ok(mut tx) = emitters.get_mut(tx) {
                tx.cancel_pending();
            }
        }
    }
}
