//! The radio's rules: next-step delivery, channels, range, aperture, 1/r² signal strength,
//! emitter direction, and queue overflow.

use bevy::math::Vec3;
use bevy::prelude::*;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{BROADCAST, Emitter, InArena, Mount, Receiver, SimClock, SimSet, SimSettings, SpawnOptions};

use crate::common::{model_from, robot_app};

const POST: &str = r#"<robot name="post"><link name="world"/></robot>"#;

/// An app with one fixed robot whose link carries an emitter at the origin (facing +X) and
/// receivers at the given offsets; the emitter sends `packets` during control step 3.
fn radio(emitter: Emitter, receivers: &[(Vec3, Receiver)], packets: &[&[u8]]) -> (App, Vec<Entity>) {
    let (mut app, arena, robot) = robot_app(&model_from(POST), SpawnOptions::default(), SimSettings::default());
    let link = robot.link("world").unwrap();
    let at = |p: Vec3| Mount { link, offset: Pose::from_translation(p) };
    app.world_mut().spawn((emitter, at(Vec3::ZERO), InArena(arena)));
    let ids = receivers.iter().map(|(p, r)| app.world_mut().spawn((r.clone(), at(*p), InArena(arena))).id()).collect();
    let packets: Vec<Vec<u8>> = packets.iter().map(|p| p.to_vec()).collect();
    app.add_systems(
        Update,
        (move |clock: Res<SimClock>, mut e: Query<&mut Emitter>| {
            if clock.control_steps == 3 {
                for p in &packets {
                    e.single_mut().unwrap().send(p.clone());
                }
            }
        })
        .in_set(SimSet::Task),
    );
    (app, ids)
}

fn queue(app: &App, receiver: Entity) -> usize {
    app.world().get::<Receiver>(receiver).unwrap().queue_length()
}

#[test]
fn a_packet_sent_during_a_step_arrives_at_the_start_of_the_next() {
    let (mut app, r) = radio(Emitter::new(1), &[(Vec3::X, Receiver::new(1))], &[b"hi"]);
    for _ in 0..4 {
        app.update(); // control steps 0..=3; the packet is sent during step 3
    }
    assert_eq!(queue(&app, r[0]), 0, "not yet: it is in the air");
    app.update();
    let mut rx = app.world_mut().get_mut::<Receiver>(r[0]).unwrap();
    assert_eq!(rx.next_packet().unwrap().data, b"hi");
    assert_eq!(rx.queue_length(), 0);
}

#[test]
fn channels_select_who_hears() {
    let rx = [(Vec3::X, Receiver::new(1)), (Vec3::X, Receiver::new(2)), (Vec3::X, Receiver::new(BROADCAST))];
    let (mut app, r) = radio(Emitter::new(1), &rx, &[b"a"]);
    for _ in 0..5 {
        app.update();
    }
    assert_eq!([queue(&app, r[0]), queue(&app, r[1]), queue(&app, r[2])], [1, 0, 1]);

    let (mut app, r) = radio(Emitter::new(BROADCAST), &rx, &[b"a"]);
    for _ in 0..5 {
        app.update();
    }
    assert_eq!([queue(&app, r[0]), queue(&app, r[1]), queue(&app, r[2])], [1, 1, 1]);
}

#[test]
fn packets_are_lost_out_of_range_and_weaken_as_one_over_r_squared() {
    let rx = [(Vec3::new(1.5, 0.0, 0.0), Receiver::new(1)), (Vec3::new(0.0, 3.0, 0.0), Receiver::new(1))];
    let (mut app, r) = radio(Emitter::new(1).with_range(2.0), &rx, &[b"a"]);
    for _ in 0..5 {
        app.update();
    }
    assert_eq!(queue(&app, r[1]), 0, "3 m is beyond the 2 m range");
    let p = app.world().get::<Receiver>(r[0]).unwrap().peek().unwrap().clone();
    assert!((p.signal_strength - 1.0 / 2.25).abs() < 1e-5, "{}", p.signal_strength);
    assert!((p.emitter_direction - Vec3::NEG_X).length() < 1e-5, "{}", p.emitter_direction);
}

#[test]
fn aperture_limits_the_cone_the_emitter_reaches() {
    let rx = [(Vec3::new(2.0, 0.2, 0.0), Receiver::new(1)), (Vec3::new(0.0, 2.0, 0.0), Receiver::new(1))];
    let (mut app, r) = radio(Emitter::new(1).with_aperture(0.3), &rx, &[b"a"]);
    for _ in 0..5 {
        app.update();
    }
    assert_eq!([queue(&app, r[0]), queue(&app, r[1])], [1, 0]);
}

#[test]
fn a_full_queue_drops_what_does_not_fit() {
    let rx = [(Vec3::X, Receiver::new(1).with_buffer_size(10))];
    let (mut app, r) = radio(Emitter::new(1), &rx, &[b"aaaa", b"bbbb", b"cccc"]);
    for _ in 0..5 {
        app.update();
    }
    let rx = app.world().get::<Receiver>(r[0]).unwrap();
    assert_eq!((rx.queue_length(), rx.dropped), (2, 1));
    assert_eq!(rx.peek().unwrap().data, b"aaaa", "first in, first out");
}
