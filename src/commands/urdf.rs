//! `twinbots urdf FILE [--png OUT] [--seconds S]`: checks a robot description (docs/urdf.md), a
//! URDF or a robot file (`*.toml`: its URDF standing at home, its chain);
//! `--tool LINK --fk q1,…,qn` prints the tool link's pose in the base link's frame instead.

use std::path::PathBuf;

use bevy::math::Vec3;
use twinbots_render::renderer::{Renderer, View};
use twinbots_sim::rapier::prelude::Pose;
use twinbots_sim::urdf::chain::Chain;
use twinbots_sim::urdf::check::{check, check_model};
use twinbots_sim::urdf::dynamics::{Dynamics, GRAVITY};
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sim::urdf::{RobotModel, Shape};

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The URDF file (meshes: STL, OBJ, glTF, Collada; package:// through TWINBOTS_PACKAGE_PATH
    /// and ROS_PACKAGE_PATH), or a robot file (`*.toml`): its URDF at its home pose, and its
    /// base and tool unless --base and --tool say otherwise.
    pub file: PathBuf,
    /// Render the robot, standing, to this PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// How long it stands in the arena (s).
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// Links whose collision meshes are split into convex parts (V-HACD) rather than wrapped
    /// in one hull, comma-separated (a concave nest or bin).
    #[arg(long, value_delimiter = ',')]
    pub decompose: Vec<String>,
    /// The chain's base link (default: the root link).
    #[arg(long)]
    pub base: Option<String>,
    /// The chain's tool link: with it, the command prints the chain from the base to it.
    #[arg(long)]
    pub tool: Option<String>,
    /// Joint positions of the chain's movable joints, in chain order (rad or m), separated by
    /// commas: prints the tool link's pose in the base link's frame as `x y z qx qy qz qw` (m, a
    /// unit quaternion), in double precision, and nothing else. Repeat it for more configurations
    /// (a line each).
    #[arg(long, requires = "tool", allow_hyphen_values = true)]
    pub fk: Vec<String>,
    /// Inverse dynamics of the chain: `q1,…,qn;qd1,…;qdd1,…` (positions, speeds, accelerations of
    /// its movable joints): prints the joint efforts (N·m or N) that move it so under gravity
    /// (9.81 m/s² down the base's z), with the URDF's inertials, and nothing else. Repeat it for
    /// more states (a line each).
    #[arg(long = "id", requires = "tool", allow_hyphen_values = true)]
    pub inverse_dynamics: Vec<String>,
}

/// `twinbots urdf`.
pub fn exec(mut args: Args) -> anyhow::Result<()> {
    let robot_file =
        RobotFile::is_path(&args.file.to_string_lossy()).then(|| RobotFile::read(&args.file)).transpose()?;
    if let Some(file) = &robot_file {
        args.base = args.base.take().or_else(|| Some(file.chain.base.clone()));
        args.tool = args.tool.take().or_else(|| Some(file.chain.tool.clone()));
    }
    if let Some(tool) = &args.tool {
        let chain = match &robot_file {
            Some(file)
                if file.chain.base == *args.base.as_ref().unwrap_or(&String::new()) && file.chain.tool == *tool =>
            {
                file.chain.clone()
            }
            Some(file) => Chain::from_file(&file.urdf, args.base.as_deref(), tool)?,
            None => Chain::from_file(&args.file, args.base.as_deref(), tool)?,
        };
        if !args.fk.is_empty() {
            return print_poses(&chain, &args.fk);
        }
        if !args.inverse_dynamics.is_empty() {
            return print_efforts(&chain, &args.inverse_dynamics);
        }
        let joints: Vec<&str> = chain.movable().map(|j| j.name.as_str()).collect();
        println!("chain {} -> {}: {} movable joints: {}", chain.base, chain.tool, joints.len(), joints.join(", "));
    }
    // The pose it stands in: a robot file's home, a bare URDF's zero.
    let stand: Vec<(String, f32)> = robot_file
        .as_ref()
        .map(|file| file.joints.iter().cloned().zip(file.home.iter().map(|&q| q as f32)).collect())
        .unwrap_or_default();
    let mut report = match &robot_file {
        Some(file) => {
            println!("home: {}", stand.iter().map(|(j, q)| format!("{j} {q}")).collect::<Vec<_>>().join(", "));
            check_model(file.model()?, args.seconds, &args.decompose, &stand, twinbots_arm::sim_settings(file))?
        }
        None => check(&args.file, args.seconds, &args.decompose)?,
    };
    let m = &report.model;
    let mass: f32 = m.links.iter().filter_map(|l| l.inertial.map(|i| i.mass)).sum();
    let movable = m.joints.iter().filter(|j| j.kind.is_movable()).count();
    let motors = m.joints.iter().filter(|j| j.kind.is_movable() && j.limits.effort > 0.0).count();
    println!(
        "{}: robot '{}', {} links, {} joints ({movable} movable, {motors} with motors), {mass:.3} kg",
        args.file.display(),
        m.name,
        m.links.len(),
        m.joints.len()
    );
    for line in &report.tree {
        println!("  {line}");
    }
    println!(
        "stood {:.1} s, base welded, drives holding 0: fastest joint {} at {:.3}",
        report.seconds,
        if report.fastest.1.is_empty() { "(none)" } else { &report.fastest.1 },
        report.fastest.0
    );
    for (joint, position, effort) in &report.holding {
        println!("  holding {joint} at {position:.5}: effort {effort:.4}");
    }
    if report.warnings.is_empty() {
        println!("no warnings");
    }
    for w in &report.warnings {
        println!("warning: {w}");
    }
    if let Some(png) = &args.png {
        let (width, height) = (800, 600);
        let mut renderer = Renderer::new(width, height)?;
        let (target, size) = extent(&report.model, &stand);
        // Far enough for the robot to fill about two thirds of the 45° view.
        let eye = target + Vec3::new(0.5, -1.3, 0.6).normalize() * size.max(0.2) * 1.7;
        renderer.set_view(View::looking_at(eye, target, 45f32.to_radians()));
        renderer.sync(report.app.world_mut(), report.arena);
        let rgb = renderer.render()?;
        image::save_buffer(png, &rgb, width, height, image::ExtendedColorType::Rgb8)
            .map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?;
        println!("wrote {}", png.display());
    }
    Ok(())
}

/// `--fk`: a pose line per configuration, every number as Rust prints an f64 (shortest exact).
fn print_poses(chain: &Chain, configurations: &[String]) -> anyhow::Result<()> {
    let mut out = String::new();
    for (k, text) in configurations.iter().enumerate() {
        let q = joint_values(chain, text, &format!("--fk #{}", k + 1))?;
        let pose = chain.forward(&q);
        let (t, r) = (pose.translation, pose.rotation);
        out += &format!("{:?} {:?} {:?} {:?} {:?} {:?} {:?}\n", t.x, t.y, t.z, r.x, r.y, r.z, r.w);
    }
    print!("{out}");
    Ok(())
}

/// `--id`: the efforts per state, every number as Rust prints an f64.
fn print_efforts(chain: &Chain, states: &[String]) -> anyhow::Result<()> {
    let dynamics = Dynamics::of(chain);
    let mut out = String::new();
    for (k, text) in states.iter().enumerate() {
        let what = format!("--id #{}", k + 1);
        let parts: Vec<&str> = text.split(';').collect();
        anyhow::ensure!(parts.len() == 3, "{what}: '{text}' is not 'q…;qd…;qdd…'");
        let v: Vec<Vec<f64>> = parts.iter().map(|p| joint_values(chain, p, &what)).collect::<anyhow::Result<_>>()?;
        let tau = dynamics.inverse(&v[0], &v[1], &v[2], GRAVITY);
        out += &tau.iter().map(|t| format!("{t:?}")).collect::<Vec<_>>().join(" ");
        out.push('\n');
    }
    print!("{out}");
    Ok(())
}

/// One finite value per movable joint of `chain`, from a comma-separated list.
fn joint_values(chain: &Chain, text: &str, what: &str) -> anyhow::Result<Vec<f64>> {
    let values = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<Vec<f64>>>()
        .ok_or_else(|| anyhow::anyhow!("{what}: '{text}' is not a list of finite numbers"))?;
    anyhow::ensure!(
        values.len() == chain.dof(),
        "{what}: {} values for the {} movable joints from '{}' to '{}'",
        values.len(),
        chain.dof(),
        chain.base,
        chain.tool
    );
    Ok(values)
}

/// The centre and largest side of the box around the robot's visuals (and link frames) at
/// the zero pose.
fn extent(model: &RobotModel, stand: &[(String, f32)]) -> (Vec3, f32) {
    let pose = model.link_poses(Pose::IDENTITY, |j| stand.iter().find(|(n, _)| *n == j.name).map_or(0.0, |&(_, q)| q));
    let mut points: Vec<Vec3> = pose.iter().map(|p| p.translation).collect();
    for (l, link) in model.links.iter().enumerate() {
        for v in &link.visuals {
            let at = pose[l] * v.geometry.origin;
            match &v.geometry.shape {
                Shape::Mesh(mesh) => points.extend(mesh.vertices.iter().map(|p| at * *p)),
                Shape::Box { half_extents } => points.extend(
                    [-1.0f32, 1.0]
                        .iter()
                        .flat_map(|&s| [at * (*half_extents * s), at * (*half_extents * Vec3::new(s, -s, s))]),
                ),
                Shape::Cylinder { radius, length } => points.extend([
                    at * Vec3::new(*radius, *radius, length / 2.0),
                    at * Vec3::new(-radius, -radius, -length / 2.0),
                ]),
                Shape::Sphere { radius } => points.extend([at * Vec3::splat(*radius), at * Vec3::splat(-radius)]),
            }
        }
    }
    let (lo, hi) =
        points.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    ((lo + hi) / 2.0, (hi - lo).max_element())
}
