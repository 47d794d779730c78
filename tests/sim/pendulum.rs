//! With the cart held still, the pole swings with the period of a compound pendulum.

use bevy::math::{Quat, Vec3};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{JointState, SimSettings, SpawnOptions};

use crate::common::{robot_app, with_supervisor};

#[test]
fn pole_small_angle_period_matches_compound_pendulum() {
    let model = cartpole::model();
    // Expected period from the URDF's own numbers: T = 2π √(I_hinge / (m g d)).
    let hinge_to_body = |name: &str| {
        let link = &model.links[model.link_index(name).unwrap()];
        let inertial = link.inertial.unwrap();
        let offset = if name == "pole_tip" { 1.0 } else { 0.0 };
        let d = inertial.origin.translation.z + offset;
        let i_yy = inertial.inertia.y_axis.y;
        (inertial.mass, inertial.mass * d, i_yy + inertial.mass * d * d)
    };
    let (m1, md1, i1) = hinge_to_body("pole");
    let (m2, md2, i2) = hinge_to_body("pole_tip");
    assert!((m1 + m2 - 0.22).abs() < 1e-6);
    let g = 9.81;
    let expected = 2.0 * std::f32::consts::PI * ((i1 + i2) / ((md1 + md2) * g)).sqrt();

    // Upside down, base welded 2 m up: the pole hangs below its hinge.
    let options = SpawnOptions {
        base: Pose::from_parts(Vec3::new(0.0, 0.0, 2.0), Quat::from_rotation_x(std::f32::consts::PI)),
        fixed_base: true,
        ..Default::default()
    };
    let settings = SimSettings { dt: 0.002, substeps: 1, ..Default::default() };
    let (mut app, _, spawned) = robot_app(&model, options, settings);
    let pole = spawned.joint("pole_joint").unwrap();
    assert!(with_supervisor(&mut app, |s| s.set_joint_position(pole, 0.05)));

    let mut crossings = Vec::new();
    let mut prev = app.world().get::<JointState>(pole).unwrap().position;
    assert!((prev - 0.05).abs() < 1e-4, "the supervisor set the start angle");
    for step in 1..=4000 {
        app.update();
        let angle = app.world().get::<JointState>(pole).unwrap().position;
        if prev > 0.0 && angle <= 0.0 {
            let frac = prev / (prev - angle);
            crossings.push((step as f32 - 1.0 + frac) * settings.dt);
        }
        prev = angle;
    }
    assert!(crossings.len() >= 4, "it swings: {crossings:?}");
    let periods: Vec<f32> = crossings.windows(2).map(|w| w[1] - w[0]).collect();
    let measured = periods.iter().sum::<f32>() / periods.len() as f32;
    let error = (measured - expected).abs() / expected;
    assert!(error < 0.03, "period {measured:.4} s vs compound pendulum {expected:.4} s ({:.1}% off)", error * 100.0);
}
