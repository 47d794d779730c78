//! `twinbots urdf FILE`: a robot description checked the way a simulation engineer needs it —
//! read (errors name the file, line and element), put into a physics arena and stepped, its
//! link/joint tree listed with masses, inertias, limits and actuators, and what will not
//! simulate well flagged.

use super::{JointKind, RobotModel, load_urdf};
use crate::{
    Arena, JointState, Motor, MotorCommand, PhysicsSubstep, SimPlugin, SimSettings, SpawnOptions, spawn_robot,
};
use bevy::prelude::*;

/// What the check found.
pub struct UrdfReport {
    pub model: RobotModel,
    /// The link/joint tree, one line each, indented by depth.
    pub tree: Vec<String>,
    /// What will not simulate well, one sentence each.
    pub warnings: Vec<String>,
    /// The fastest any joint moved while the robot stood, its base welded and its drives
    /// holding (rad/s or m/s), and which joint.
    pub fastest: (f32, String),
    /// Each motorized joint at the end of the stand, in the model's joint order: its name,
    /// position (rad or m) and the effort its drive exerted holding it (N·m or N).
    pub holding: Vec<(String, f32, f32)>,
    pub seconds: f64,
    /// The app it stood in and its arena (for a picture).
    pub app: App,
    pub arena: Entity,
}

/// Reads `path`, lists and flags it, and stands it in an arena for `seconds`: base welded,
/// every drive holding its joint at 0 (a robot switched on at its zero pose; see
/// [`holding_target`] for a joint whose range excludes 0); the collision
/// meshes of the links in `decompose` split into convex parts.
pub fn check(path: &std::path::Path, seconds: f64, decompose: &[String]) -> anyhow::Result<UrdfReport> {
    check_model(load_urdf(path)?, seconds, decompose, &[], SimSettings::default())
}

/// [`check`] of a model already read, standing with the joints of `pose` held where it puts
/// them (a robot file's home) and the others as [`check`] holds them, in physics of `settings`
/// (a robot file's twin's).
pub fn check_model(
    model: RobotModel,
    seconds: f64,
    decompose: &[String],
    pose: &[(String, f32)],
    settings: SimSettings,
) -> anyhow::Result<UrdfReport> {
    anyhow::ensure!(
        seconds >= 0.0 && seconds.is_finite() && seconds <= 600.0,
        "--seconds must be from 0 to 600, not {seconds}"
    );
    if let Some(unknown) = decompose.iter().find(|n| model.link_index(n).is_none()) {
        let links: Vec<&str> = model.links.iter().map(|l| l.name.as_str()).collect();
        anyhow::bail!("--decompose: robot '{}' has no link '{unknown}' (its links: {})", model.name, links.join(", "));
    }
    for link in model.links.iter().filter(|l| decompose.contains(&l.name)) {
        for geometry in &link.collisions {
            if let crate::urdf::Shape::Mesh(mesh) = &geometry.shape {
                anyhow::ensure!(
                    mesh.triangles.len() <= crate::spawn::MAX_DECOMPOSED_TRIANGLES,
                    "--decompose: link '{}' has a collision mesh of {} triangles, more than the {} a split into \
                     convex parts takes; give the link a simpler collision mesh",
                    link.name,
                    mesh.triangles.len(),
                    crate::spawn::MAX_DECOMPOSED_TRIANGLES
                );
            }
        }
    }
    let tree = tree(&model);
    let mut warnings = flags(&model);
    let mut app = App::new();
    // A tool, not a robot: it stands the robot and draws the true world (`--png`).
    app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings, supervisor: true });
    let world = app.world_mut();
    let arena = world.spawn_empty().id();
    let mut a = Arena::new(0, 0, settings.dt, settings.gravity);
    let spawned = {
        let mut commands = world.commands();
        spawn_robot(
            &mut commands,
            arena,
            &mut a,
            &model,
            SpawnOptions {
                fixed_base: true,
                decompose: decompose.to_vec(),
                joint_positions: pose.to_vec(),
                ..Default::default()
            },
        )
    };
    world.flush();
    world.entity_mut(arena).insert(a);
    for (name, &joint) in &spawned.joints {
        let posed = pose.iter().find(|(n, _)| n == name).map(|&(_, q)| q);
        let target = posed.unwrap_or_else(|| model.joint(name).map_or(0.0, |j| holding_target(j.limits.position)));
        if let Some(mut motor) = world.get_mut::<Motor>(joint) {
            motor.command = MotorCommand::Position(target);
            // A robot file's arm stands as its tasks drive it: servos holding position.
            motor.holds_position = !pose.is_empty();
        }
    }
    app.update();
    let mut fastest = (0.0f32, String::new());
    let steps = (seconds / settings.dt_seconds()).round() as usize;
    for _ in 0..steps {
        app.world_mut().run_schedule(PhysicsSubstep);
        for (name, &joint) in &spawned.joints {
            if let Some(s) = app.world().get::<JointState>(joint) {
                let speed =
                    if s.velocity.is_finite() && s.position.is_finite() { s.velocity.abs() } else { f32::INFINITY };
                if speed > fastest.0 || (speed.is_infinite() && fastest.0.is_finite()) {
                    fastest = (speed, name.clone());
                }
            }
        }
    }
    if !fastest.0.is_finite() {
        warnings.push(format!(
            "joint '{}' left the numbers (NaN or infinite) while the robot stood: the physics blew up",
            fastest.1
        ));
    } else if fastest.0 > 50.0 {
        warnings.push(format!(
            "joint '{}' reached {:.0} rad/s (or m/s) while the robot stood: the physics is unstable",
            fastest.1, fastest.0
        ));
    }
    let holding = model
        .joints
        .iter()
        .filter_map(|j| {
            let entity = *spawned.joints.get(&j.name)?;
            app.world().get::<Motor>(entity)?;
            let s = app.world().get::<JointState>(entity)?;
            Some((j.name.clone(), s.position, s.effort))
        })
        .collect();
    let seconds = steps as f64 * settings.dt_seconds();
    Ok(UrdfReport { model, tree, warnings, fastest, holding, seconds, app, arena })
}

/// Where a drive holds its joint while the robot stands: 0, or where 0 is outside the joint's
/// range or within 5 % of the range from a limit (the Panda's fourth and sixth joints), the
/// nearest point 5 % inside it, so no joint leans on its limit.
fn holding_target(range: Option<[f32; 2]>) -> f32 {
    match range {
        Some([lo, hi]) if hi > lo => {
            let margin = 0.05 * (hi - lo);
            0.0f32.clamp(lo + margin, hi - margin)
        }
        _ => 0.0,
    }
}

fn tree(model: &RobotModel) -> Vec<String> {
    let mut out = Vec::new();
    walk(model, model.root, 0, &mut out);
    out
}

/// `link`'s line, then each joint under it followed by its child's subtree.
fn walk(model: &RobotModel, link: usize, depth: usize, out: &mut Vec<String>) {
    let l = &model.links[link];
    let pad = "  ".repeat(depth);
    let mass = match &l.inertial {
        Some(i) => {
            let d = i.inertia.to_cols_array();
            let source = if i.from_geometry { " from the collision geometry" } else { "" };
            format!("{:.3} kg, inertia diag {:.4} {:.4} {:.4} kg*m^2{source}", i.mass, d[0], d[4], d[8])
        }
        None => "massless".into(),
    };
    out.push(format!("{pad}{} ({mass}; {} collision, {} visual)", l.name, l.collisions.len(), l.visuals.len()));
    for j in model.joints.iter().filter(|j| j.parent == link) {
        let range = match (j.kind, j.limits.position) {
            (JointKind::Fixed, _) => String::new(),
            (_, Some([lo, hi])) => format!(", range [{lo:.3}, {hi:.3}]"),
            (_, None) => ", no range".into(),
        };
        let drive = if !j.kind.is_movable() {
            String::new()
        } else if j.limits.effort > 0.0 {
            format!(", motor: effort {} velocity {}", j.limits.effort, j.limits.velocity)
        } else {
            ", passive".into()
        };
        out.push(format!("{pad}  {} ({:?}{range}{drive}) -> {}", j.name, j.kind, model.links[j.child].name));
        walk(model, j.child, depth + 2, out);
    }
}

/// What will not simulate well (the loader has already refused what cannot be simulated at
/// all: a moved link without mass, an unphysical inertia, a revolute joint without `<limit>`).
fn flags(model: &RobotModel) -> Vec<String> {
    let mut out = Vec::new();
    for j in model.joints.iter().filter(|j| j.kind.is_movable()) {
        // urdf-rs reads a <limit> without lower and upper as [0, 0]: a joint that cannot move.
        if j.kind != JointKind::Continuous && j.limits.position.is_none_or(|[lo, hi]| hi <= lo) {
            out.push(format!("joint '{}' ({:?}) has no range: give <limit> its lower and upper", j.name, j.kind));
        }
        if j.limits.effort > 0.0 && j.limits.velocity <= 0.0 {
            out.push(format!("joint '{}' has a motor but no speed limit (<limit velocity>)", j.name));
        }
    }
    for l in model.links.iter().filter(|l| l.inertial.is_some_and(|i| i.mass > 0.0) && l.collisions.is_empty()) {
        out.push(format!("link '{}' has mass but no <collision>: it passes through everything", l.name));
    }
    out
}
