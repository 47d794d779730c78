//! The arm's twin under a position servo, as a UR's controller follows `servoj` targets: every
//! control period the twin's drives take the speed that brings each joint from where the twin
//! stands to the next target within the period (the target's own speed fed forward, and what
//! the twin trails by made up), limited by the joints' speeds and efforts; the physics (the
//! URDF's links under gravity, the drives' limited torque) decides where the joints get to.
//! `replay ROBOT.toml LOG` runs a recording's `target_q` through it and compares the joints
//! with the recording's `actual_q`.

use bevy::prelude::*;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sim::{Arena, JointState, Motor, MotorCommand, PhysicsSubstep, SimPlugin, SpawnOptions, spawn_robot};

use crate::arm::Arm;

/// The servo's integral gain (1/s): what the joints trail their targets by is made up over
/// about 1/gain seconds. Chosen on the real UR5's recordings (docs/logs.md): 2–5 hold the
/// shoulder's sag under gravity to under 2 mrad; from 10 the shoulder starts to swing, at 20 it
/// trails by 20 mrad, at 50 it is unstable.
pub const SERVO_INTEGRAL_GAIN: f64 = 3.0;

/// The twin's joints (the file's controlled joints, in its order) at each target's time, from
/// `start` at `times[0]`, driven towards `targets[k + 1]` over `times[k]..times[k + 1]`.
/// `targets` and `times` are as long as each other; a gap between times is stepped in whole
/// physics steps (at least one).
pub fn follow_targets(
    file: &RobotFile,
    start: &[f64],
    times: &[f64],
    targets: &[Vec<f64>],
) -> anyhow::Result<Vec<Vec<f64>>> {
    let arm = Arm::of(file.clone())?;
    let dof = arm.dof();
    anyhow::ensure!(
        start.len() == dof && targets.iter().all(|t| t.len() == dof) && targets.len() == times.len(),
        "{} joints, {} start values, {} targets at {} times: they do not match",
        dof,
        start.len(),
        targets.len(),
        times.len()
    );
    let settings = crate::sim_settings(file);
    let mut app = App::new();
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings, supervisor: true });
    let world = app.world_mut();
    let entity = world.spawn_empty().id();
    let mut arena = Arena::new(0, 0, settings.dt, settings.gravity);
    let joint_positions: Vec<(String, f32)> =
        file.joints.iter().cloned().zip(start.iter().map(|&q| q as f32)).collect();
    let robot = {
        let mut commands = world.commands();
        spawn_robot(
            &mut commands,
            entity,
            &mut arena,
            &arm.model,
            SpawnOptions { fixed_base: true, joint_positions, ..default() },
        )
    };
    world.flush();
    world.entity_mut(entity).insert(arena);
    let joints: Vec<Entity> = file
        .joints
        .iter()
        .map(|name| robot.joint(name).ok_or_else(|| anyhow::anyhow!("the twin has no joint '{name}'")))
        .collect::<anyhow::Result<_>>()?;
    // Drives that hold a position reference (the robot's own joint position loops), which
    // the servo's trajectory generator below moves along the targets.
    for &joint in &joints {
        if let Some(mut motor) = world.get_mut::<Motor>(joint) {
            motor.holds_position = true;
            motor.command = MotorCommand::Velocity(0.0);
        }
    }
    // Start-up: the world as built.
    app.update();
    let read = |world: &World| -> Vec<f64> {
        joints.iter().map(|&j| world.get::<JointState>(j).map_or(f64::NAN, |s| s.position as f64)).collect()
    };
    let mut out = Vec::with_capacity(times.len());
    out.push(read(app.world()));
    // The drives' reference: where the trajectory generator has put it (it moves the reference
    // a speed × the physics steps each period, as the motors integrate it).
    let mut reference = out[0].clone();
    // What the drives' position loops leave under load (gravity holds a shoulder a little
    // below its reference), integrated and added to the reference: the servo's integral action.
    let mut integral = vec![0.0; dof];
    for k in 0..times.len().saturating_sub(1) {
        let steps = (((times[k + 1] - times[k]) / settings.dt as f64).round() as usize).max(1);
        let span = steps as f64 * settings.dt as f64;
        let world = app.world_mut();
        for (j, &joint) in joints.iter().enumerate() {
            let Some(mut motor) = world.get_mut::<Motor>(joint) else { continue };
            // Within the drive's rated speed (the URDF's), not the tasks' safety factor: a
            // recording is what the robot did.
            let limit = motor.max_velocity as f64;
            let speed = ((targets[k + 1][j] + integral[j] - reference[j]) / span).clamp(-limit, limit);
            reference[j] += speed * span;
            motor.command = MotorCommand::Velocity(speed as f32);
        }
        for _ in 0..steps {
            world.run_schedule(PhysicsSubstep);
        }
        let q = read(app.world());
        for j in 0..dof {
            integral[j] += SERVO_INTEGRAL_GAIN * (targets[k + 1][j] - q[j]) * span;
        }
        out.push(q);
    }
    Ok(out)
}
