//! Webots' Emitter and Receiver (radio type): byte packets on channels, delivered at the start of
//! the next control step to receivers in the same arena that listen on the channel, are within
//! range and inside the emitter's aperture; signal strength falls as 1/r²; each receiver keeps a
//! queue bounded in bytes (what does not fit is dropped and counted).

use std::collections::VecDeque;

use bevy::math::Vec3;
use bevy::prelude::*;

use super::mount::Mount;
use crate::SimSet;
use crate::arena::{Arena, InArena};
use crate::robot::Link;

/// Radio delivery, first in every control step (`SimSet::Radio`).
pub struct RadioPlugin;

impl Plugin for RadioPlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(Update, deliver_radio.in_set(SimSet::Radio));
    }
}

/// The channel that reaches (or listens to) every channel.
pub const BROADCAST: i32 = -1;

/// Sends packets. Packets sent during a control step arrive at the start of the next.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Emitter {
    pub channel: i32,
    /// Maximum distance (m); `None` for unlimited.
    pub range: Option<f32>,
    /// Half-angle (rad) of the cone around the mount's +X that packets reach; `None` for all
    /// directions.
    pub aperture: Option<f32>,
    outbox: Vec<Vec<u8>>,
}

impl Emitter {
    pub fn new(channel: i32) -> Self {
        Self { channel, range: None, aperture: None, outbox: Vec::new() }
    }

    pub fn with_range(mut self, range: f32) -> Self {
        self.range = Some(range);
        self
    }

    pub fn with_aperture(mut self, half_angle: f32) -> Self {
        self.aperture = Some(half_angle);
        self
    }

    /// Drops packets sent this step and not yet delivered (used at episode resets).
    pub fn cancel_pending(&mut self) {
        self.outbox.clear();
    }

    /// Queues a packet for transmission at the end of this control step.
    pub fn send(&mut self, data: impl Into<Vec<u8>>) {
        self.outbox.push(data.into());
    }
}

/// A received packet.
#[derive(Clone, Debug, PartialEq)]
pub struct Packet {
    pub data: Vec<u8>,
    pub channel: i32,
    /// 1 / r², r the emitter–receiver distance (m); infinite at zero distance.
    pub signal_strength: f32,
    /// Unit vector towards the emitter, in the receiver's frame.
    pub emitter_direction: Vec3,
}

/// Receives packets into a queue.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Receiver {
    pub channel: i32,
    /// Queue capacity in bytes of payload; `None` for unlimited.
    pub buffer_size: Option<usize>,
    queue: VecDeque<Packet>,
    /// Packets lost because the queue was full.
    pub dropped: u64,
}

impl Receiver {
    pub fn new(channel: i32) -> Self {
        Self { channel, buffer_size: None, queue: VecDeque::new(), dropped: 0 }
    }

    pub fn with_buffer_size(mut self, bytes: usize) -> Self {
        self.buffer_size = Some(bytes);
        self
    }

    pub fn queue_length(&self) -> usize {
        self.queue.len()
    }

    /// The oldest packet, without removing it.
    pub fn peek(&self) -> Option<&Packet> {
        self.queue.front()
    }

    /// Removes and returns the oldest packet (Webots' `getData` then `nextPacket`).
    pub fn next_packet(&mut self) -> Option<Packet> {
        self.queue.pop_front()
    }

    /// Empties the queue (used at episode resets).
    pub fn clear(&mut self) {
        self.queue.clear();
    }

    fn queued_bytes(&self) -> usize {
        self.queue.iter().map(|p| p.data.len()).sum()
    }

    fn accept(&mut self, packet: Packet) {
        if self.buffer_size.is_some_and(|cap| self.queued_bytes() + packet.data.len() > cap) {
            self.dropped += 1;
        } else {
            self.queue.push_back(packet);
        }
    }
}

fn listens(receiver: i32, sender: i32) -> bool {
    receiver == BROADCAST || sender == BROADCAST || receiver == sender
}

/// Delivers every packet sent during the previous control step.
fn deliver_radio(
    links: Query<&Link>,
    arenas: Query<&Arena>,
    mut emitters: Query<(&mut Emitter, &Mount, &InArena)>,
    mut receivers: Query<(&mut Receiver, &Mount, &InArena)>,
) {
    for (mut emitter, e_mount, e_arena) in &mut emitters {
        if emitter.outbox.is_empty() {
            continue;
        }
        let packets = std::mem::take(&mut emitter.outbox);
        let Ok(arena) = arenas.get(e_arena.0) else { continue };
        let Some(from) = e_mount.state(&links, &arena.world) else { continue };
        for (mut receiver, r_mount, r_arena) in &mut receivers {
            if r_arena != e_arena || !listens(receiver.channel, emitter.channel) {
                continue;
            }
            let Some(to) = r_mount.state(&links, &arena.world) else { continue };
            let offset = to.pose.translation - from.pose.translation;
            let r = offset.length();
            if emitter.range.is_some_and(|range| r > range) {
                continue;
            }
            if let Some(half_angle) = emitter.aperture {
                let forward = from.pose.rotation * Vec3::X;
                if r > 0.0 && forward.angle_between(offset) > half_angle {
                    continue;
                }
            }
            let direction = if r > 0.0 { to.pose.rotation.inverse() * (-offset / r) } else { Vec3::ZERO };
            for data in &packets {
                receiver.accept(Packet {
                    data: data.clone(),
                    channel: emitter.channel,
                    signal_strength: 1.0 / (r * r),
                    emitter_direction: direction,
                });
            }
        }
    }
}
