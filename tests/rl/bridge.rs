//! The channel bridge: steps match direct stepping, and either side ending ends the other.

use bevy::prelude::*;
use twinbots_api::{SingleEnv, VecEnv};
use twinbots_sim::SimSet;
use twinbots_task::bridge::{self, BridgePlugin};
use twinbots_task::{AppVecEnv, env};

fn bridged_app(arenas: usize) -> (App, bridge::ChannelVecEnv) {
    let mut app = cartpole::headless_app(arenas, 4);
    app.add_plugins(BridgePlugin);
    env::start(&mut app).unwrap();
    let channel = bridge::connect(app.world_mut()).unwrap();
    (app, channel)
}

#[test]
fn bridged_steps_equal_direct_steps_and_the_app_stops_when_the_trainer_hangs_up() {
    let actions: Vec<f32> = (0..60).map(|i| ((i / 3) % 2) as f32).flat_map(|a| [a, 1.0 - a]).collect();
    let mut direct = AppVecEnv::new(cartpole::headless_app(2, 4));
    let mut expected = vec![direct.reset(Some(4)).unwrap()];
    for a in actions.chunks(2) {
        expected.push(direct.step(a).unwrap().obs);
    }
    let (mut app, mut channel) = bridged_app(2);
    let trainer = std::thread::spawn(move || {
        let mut got = vec![channel.reset(Some(4)).unwrap()];
        for a in actions.chunks(2) {
            got.push(channel.step(a).unwrap().obs);
        }
        got // dropping the channel hangs up
    });
    bridge::run_until_closed(&mut app); // returns only because the trainer hung up
    assert_eq!(trainer.join().unwrap(), expected);
}

#[test]
fn a_refused_request_is_an_error_and_the_bridge_keeps_serving() {
    let (mut app, mut channel) = bridged_app(2);
    let trainer = std::thread::spawn(move || {
        channel.reset(None).unwrap();
        let err = channel.step(&[1.0]).unwrap_err().to_string();
        let ok = channel.step(&[1.0, 0.0]).is_ok();
        (err, ok)
    });
    bridge::run_until_closed(&mut app);
    let (err, ok) = trainer.join().unwrap();
    assert!(err.contains("expected 2 arenas"), "{err}");
    assert!(ok, "a good step after a bad one still works");
}

#[derive(Resource)]
struct PanicAt(u32);

fn panic_on_step(mut at: ResMut<PanicAt>) {
    at.0 -= 1;
    assert!(at.0 > 0, "simulated crash in the app");
}

#[test]
fn the_trainer_gets_an_error_when_the_app_panics() {
    let (mut app, mut channel) = bridged_app(1);
    app.insert_resource(PanicAt(5)).add_systems(Update, panic_on_step.in_set(SimSet::Task));
    let trainer = std::thread::spawn(move || {
        channel.reset(None).unwrap();
        (0..100).map(|_| channel.step(&[1.0])).find_map(Result::err).map(|e| e.to_string())
    });
    let crashed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| bridge::run_until_closed(&mut app)));
    assert!(crashed.is_err());
    drop(app);
    let err = trainer.join().unwrap().expect("the trainer saw an error");
    assert!(err.contains("simulation app has stopped"), "{err}");
}

#[test]
fn single_env_has_gymnasiums_surface() {
    let mut env = SingleEnv::new(AppVecEnv::new(cartpole::headless_app(1, 2))).unwrap();
    let (obs, _) = env.reset(Some(2)).unwrap();
    assert_eq!(obs.len(), 4);
    assert!(env.step(&[2.0]).is_err(), "2 is not in Discrete(2)");
    let mut ended = None;
    for _ in 0..500 {
        let (_, reward, terminated, truncated, info) = env.step(&[1.0]).unwrap();
        assert_eq!(reward, 1.0);
        if terminated || truncated {
            ended = Some(info);
            break;
        }
    }
    let info = ended.expect("driving one way ends the episode");
    let last = info.final_observation.expect("final observation kept");
    assert!(last[0].abs() > 0.39 || last[2].abs() > 0.26, "it ended at a limit: {last:?}");
    assert!(info.episode.unwrap().length > 0);
}
