//! Reading and checking a URDF: roxmltree finds the lines, urdf-rs reads the schema, and the
//! checks here reject what the simulator cannot build (loops, two parents, missing meshes, ...).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bevy::math::{EulerRot, Mat3, Quat, Vec3};

use super::error::UrdfError;
use super::mesh::NamedPackages;
use super::model::*;
use super::xml_depth::{MAX_XML_DEPTH, too_deep};
use crate::rapier::math::Pose;

/// Reads and checks a URDF file; meshes are looked up relative to its folder.
pub fn load_urdf(path: impl AsRef<Path>) -> Result<RobotModel, UrdfError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|source| UrdfError::Io { file: path.to_path_buf(), source })?;
    let base = path.parent().unwrap_or(Path::new("."));
    parse_urdf(&text, path, base)
}

/// The XML of URDF text, its numbers checked; errors name the file, line and column.
fn parse_xml<'t>(text: &'t str, file: &Path) -> Result<roxmltree::Document<'t>, UrdfError> {
    if let Some(line) = too_deep(text) {
        return Err(UrdfError::Xml {
            file: file.to_path_buf(),
            line: line as u32,
            column: 1,
            message: format!("elements nest deeper than {MAX_XML_DEPTH} levels"),
        });
    }
    let doc = roxmltree::Document::parse(text).map_err(|e| {
        let pos = e.pos();
        UrdfError::Xml { file: file.to_path_buf(), line: pos.row, column: pos.col, message: e.to_string() }
    })?;
    check_numbers(&doc, file)?;
    Ok(doc)
}

fn read_robot(text: &str, doc: &roxmltree::Document, file: &Path) -> Result<urdf_rs::Robot, UrdfError> {
    urdf_rs::read_from_string(&with_zero_inertias(text, doc))
        .map_err(|e| UrdfError::Schema { file: file.to_path_buf(), message: e.to_string() })
}

/// URDF text as `urdf-rs` reads it, in double precision, its XML and numbers checked as
/// [`parse_urdf`] checks them (meshes not read): what [`super::chain`] computes kinematics from.
pub fn parse_urdf_exact(text: &str, file: &Path) -> Result<urdf_rs::Robot, UrdfError> {
    read_robot(text, &parse_xml(text, file)?, file)
}

/// Checks URDF text. `file` names it in errors; `mesh_dir` is where relative mesh paths start.
pub fn parse_urdf(text: &str, file: &Path, mesh_dir: &Path) -> Result<RobotModel, UrdfError> {
    parse_urdf_in(text, file, mesh_dir, &[], super::model::MAX_HULL_VERTICES)
}

/// Reads and checks a URDF file as [`load_urdf`], `package://` meshes found first in the
/// packages a robot file names ([`super::mesh::resolve_in`]), collision hulls of at most
/// `max_hull_vertices` vertices (its `hull_vertices`).
pub fn load_urdf_in(path: &Path, packages: &NamedPackages, max_hull_vertices: usize) -> Result<RobotModel, UrdfError> {
    let text = std::fs::read_to_string(path).map_err(|source| UrdfError::Io { file: path.to_path_buf(), source })?;
    parse_urdf_in(&text, path, path.parent().unwrap_or(Path::new(".")), packages, max_hull_vertices)
}

/// [`parse_urdf`] with a robot file's named packages and hull size.
pub fn parse_urdf_in(
    text: &str,
    file: &Path,
    mesh_dir: &Path,
    packages: &NamedPackages,
    max_hull_vertices: usize,
) -> Result<RobotModel, UrdfError> {
    let doc = parse_xml(text, file)?;
    let lines = ElementLines::index(&doc);
    let robot = read_robot(text, &doc, file)?;
    let materials = robot
        .materials
        .iter()
        .filter_map(|m| m.color.as_ref().map(|c| (m.name.clone(), c.rgba.0.map(|x| x as f32))))
        .collect();
    let package_path = super::mesh::package_path_from_env();
    Checker { file, mesh_dir, packages, package_path, lines: &lines, materials, max_hull_vertices }.build(&robot)
}

/// `text` with an all-zero `<inertia/>` in every `<inertial>` that has none (urdf-rs requires
/// it; CAD exports often give only the mass): such a link takes its collision geometry's
/// ([`solid_of`]). Inserted on the same line, so error lines stay the file's.
fn with_zero_inertias(text: &str, doc: &roxmltree::Document) -> String {
    const ZERO: &str = r#"<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>"#;
    const CLOSE: &str = "</inertial>";
    let mut at: Vec<usize> = doc
        .descendants()
        .filter(|n| n.has_tag_name("inertial") && !n.children().any(|c| c.has_tag_name("inertia")))
        .filter(|&n| text[n.range()].ends_with(CLOSE))
        .map(|n| n.range().end - CLOSE.len())
        .collect();
    let mut out = text.to_string();
    at.sort_unstable();
    for &i in at.iter().rev() {
        out.insert_str(i, ZERO);
    }
    out
}

/// The mass properties of `shapes` as one uniform solid of `mass` kg: centre of mass and
/// inertia about it, in the link's axes (convex hulls for meshes, as the collisions are).
fn solid_of(shapes: &[Geometry], mass: f32) -> Inertial {
    let mut total = crate::rapier::prelude::MassProperties::default();
    for g in shapes {
        let (shape, local) = g.shape.parry().expect("meshes are checked for a hull when read");
        total += shape.mass_properties(1.0).transform_by(&(g.origin * local));
    }
    total.set_mass(mass, true);
    Inertial {
        origin: Pose::from_translation(total.local_com),
        mass,
        inertia: total.reconstruct_inertia_matrix(),
        from_geometry: true,
    }
}

/// Attributes that hold numbers (one or several, space-separated) in the URDF schema.
const NUMBER_ATTRIBUTES: &[&str] = &[
    "xyz",
    "rpy",
    "size",
    "radius",
    "length",
    "value",
    "ixx",
    "ixy",
    "ixz",
    "iyy",
    "iyz",
    "izz",
    "effort",
    "velocity",
    "lower",
    "upper",
    "damping",
    "friction",
    "scale",
    "rgba",
    "multiplier",
    "offset",
    "rising",
    "falling",
    "k_position",
    "k_velocity",
    "soft_lower_limit",
    "soft_upper_limit",
];

/// No physical quantity of a robot cell is this large in SI units; beyond it f32 physics loses
/// all precision (and 1e39 is infinite as f32).
const LARGEST_NUMBER: f64 = 1e9;

/// Every number of the document finite and within ±1e9, or an error naming the line, the
/// link or joint it belongs to, the element and the attribute. (urdf-rs reads `nan` and `inf`
/// as numbers, and the physics would fail on them much later.)
fn check_numbers(doc: &roxmltree::Document, file: &Path) -> Result<(), UrdfError> {
    for node in doc.descendants().filter(|n| n.is_element()) {
        for attribute in node.attributes().filter(|a| NUMBER_ATTRIBUTES.contains(&a.name())) {
            let bad = attribute
                .value()
                .split_whitespace()
                .filter_map(|token| token.parse::<f64>().ok())
                .find(|x| !x.is_finite() || x.abs() > LARGEST_NUMBER);
            let Some(bad) = bad else { continue };
            let owner = node
                .ancestors()
                .find(|a| a.has_tag_name("link") || a.has_tag_name("joint") || a.has_tag_name("material"));
            let (element, name) = match owner {
                Some(o) if o.has_tag_name("link") => ("link", o.attribute("name").unwrap_or_default()),
                Some(o) if o.has_tag_name("joint") => ("joint", o.attribute("name").unwrap_or_default()),
                Some(o) => ("material", o.attribute("name").unwrap_or_default()),
                None => ("robot", doc.root_element().attribute("name").unwrap_or_default()),
            };
            return Err(UrdfError::Element {
                file: file.to_path_buf(),
                line: doc.text_pos_at(node.range().start).row,
                element,
                name: name.to_string(),
                problem: format!(
                    "<{} {}=\"{}\">: {bad} is not a finite number within ±{LARGEST_NUMBER:e}",
                    node.tag_name().name(),
                    attribute.name(),
                    attribute.value()
                ),
            });
        }
    }
    Ok(())
}

/// Line numbers of `<link>` and `<joint>` elements, and which joints have a `<limit>`.
struct ElementLines {
    links: HashMap<String, u32>,
    joints: HashMap<String, u32>,
    joints_with_limit: Vec<String>,
}

impl ElementLines {
    fn index(doc: &roxmltree::Document) -> Self {
        let mut links = HashMap::new();
        let mut joints = HashMap::new();
        let mut joints_with_limit = Vec::new();
        for node in doc.root_element().children().filter(|n| n.is_element()) {
            let Some(name) = node.attribute("name") else { continue };
            let line = doc.text_pos_at(node.range().start).row;
            match node.tag_name().name() {
                // The first definition keeps its line; duplicates are reported by name.
                "link" => {
                    links.entry(name.to_string()).or_insert(line);
                }
                "joint" => {
                    joints.entry(name.to_string()).or_insert(line);
                    if node.children().any(|c| c.has_tag_name("limit")) {
                        joints_with_limit.push(name.to_string());
                    }
                }
                _ => {}
            }
        }
        Self { links, joints, joints_with_limit }
    }
}

struct Checker<'a> {
    file: &'a Path,
    mesh_dir: &'a Path,
    /// Packages a robot file names, looked in before `package_path`.
    packages: &'a NamedPackages,
    /// Where `package://` meshes are looked for ([`super::mesh::resolve`]).
    package_path: Vec<PathBuf>,
    lines: &'a ElementLines,
    /// Colours of the robot's top-level `<material>`s, which visuals may name.
    materials: HashMap<String, [f32; 4]>,
    /// The most vertices a collision hull keeps ([`super::model::collision_hull`]).
    max_hull_vertices: usize,
}

impl Checker<'_> {
    fn link_error(&self, name: &str, problem: impl Into<String>) -> UrdfError {
        UrdfError::Element {
            file: self.file.to_path_buf(),
            line: self.lines.links.get(name).copied().unwrap_or(0),
            element: "link",
            name: name.to_string(),
            problem: problem.into(),
        }
    }

    fn joint_error(&self, name: &str, problem: impl Into<String>) -> UrdfError {
        UrdfError::Element {
            file: self.file.to_path_buf(),
            line: self.lines.joints.get(name).copied().unwrap_or(0),
            element: "joint",
            name: name.to_string(),
            problem: problem.into(),
        }
    }

    fn build(&self, robot: &urdf_rs::Robot) -> Result<RobotModel, UrdfError> {
        if robot.links.is_empty() {
            return Err(UrdfError::Schema {
                file: self.file.to_path_buf(),
                message: format!("robot '{}' has no <link>", robot.name),
            });
        }
        let mut index = HashMap::new();
        let mut links = Vec::with_capacity(robot.links.len());
        for link in &robot.links {
            if index.insert(link.name.clone(), links.len()).is_some() {
                return Err(self.link_error(&link.name, "a second link with this name"));
            }
            links.push(self.link(link)?);
        }
        let mut parent_of: Vec<Option<usize>> = vec![None; links.len()];
        let mut joints = Vec::with_capacity(robot.joints.len());
        for joint in &robot.joints {
            let model = self.joint(joint, &index)?;
            if let Some(first) = parent_of[model.child] {
                let first: &JointModel = &joints[first];
                return Err(self.joint_error(
                    &joint.name,
                    format!("link '{}' has two parents: joint '{}' already moves it", joint.child.link, first.name),
                ));
            }
            parent_of[model.child] = Some(joints.len());
            joints.push(model);
        }
        self.check_tree(&links, &joints, &parent_of)?;
        let root = parent_of.iter().position(Option::is_none).unwrap_or(0);
        self.check_masses(&links, &joints, root)?;
        Ok(RobotModel { name: robot.name.clone(), links, joints, root })
    }

    /// Exactly one root, and following parents from any link ends there (no loop).
    fn check_tree(
        &self,
        links: &[LinkModel],
        joints: &[JointModel],
        parent_of: &[Option<usize>],
    ) -> Result<(), UrdfError> {
        let roots: Vec<usize> = (0..links.len()).filter(|&l| parent_of[l].is_none()).collect();
        for start in 0..links.len() {
            let mut link = start;
            for _ in 0..=links.len() {
                match parent_of[link] {
                    Some(j) => link = joints[j].parent,
                    None => break,
                }
            }
            if let Some(j) = parent_of[link] {
                return Err(self.joint_error(
                    &joints[j].name,
                    "the joints form a loop: following parents from here never reaches a root link",
                ));
            }
        }
        if roots.len() > 1 {
            return Err(self.link_error(
                &links[roots[1]].name,
                format!(
                    "a second root: neither this link nor '{}' is the child of a joint (a robot is one tree)",
                    links[roots[0]].name
                ),
            ));
        }
        Ok(())
    }

    /// A link a joint moves must carry mass, itself or through links fixed to it.
    fn check_masses(&self, links: &[LinkModel], joints: &[JointModel], root: usize) -> Result<(), UrdfError> {
        for joint in joints.iter().filter(|j| j.kind.is_movable()) {
            let mut stack = vec![joint.child];
            let mut mass = 0.0;
            while let Some(l) = stack.pop() {
                mass += links[l].inertial.map_or(0.0, |i| i.mass);
                stack.extend(joints.iter().filter(|c| c.parent == l && c.kind == JointKind::Fixed).map(|c| c.child));
            }
            if mass <= 0.0 {
                return Err(self.link_error(
                    &links[joint.child].name,
                    format!(
                        "moved by joint '{}' but has no mass: give it an <inertial> with a positive mass",
                        joint.name
                    ),
                ));
            }
        }
        let _ = root;
        Ok(())
    }

    fn link(&self, link: &urdf_rs::Link) -> Result<LinkModel, UrdfError> {
        let inertial = &link.inertial;
        let mass = inertial.mass.value as f32;
        if !mass.is_finite() || mass < 0.0 {
            return Err(self.link_error(&link.name, format!("negative or invalid mass {mass}")));
        }
        let i = &inertial.inertia;
        let inertia = Mat3::from_cols_array(&[
            i.ixx as f32,
            i.ixy as f32,
            i.ixz as f32,
            i.ixy as f32,
            i.iyy as f32,
            i.iyz as f32,
            i.ixz as f32,
            i.iyz as f32,
            i.izz as f32,
        ]);
        let diag = [i.ixx, i.iyy, i.izz];
        if diag.iter().any(|d| !d.is_finite() || *d < 0.0)
            || diag[0] + diag[1] < diag[2] - 1e-9
            || diag[1] + diag[2] < diag[0] - 1e-9
            || diag[0] + diag[2] < diag[1] - 1e-9
        {
            return Err(self.link_error(
                &link.name,
                "inertia is not physical: ixx, iyy, izz must be non-negative and obey the triangle inequality",
            ));
        }
        let collisions: Vec<Geometry> = link
            .collision
            .iter()
            .map(|c| self.geometry(&link.name, &c.origin, &c.geometry))
            .collect::<Result<_, _>>()?;
        // A mass without an inertia (CAD exports often leave it out): the collision geometry's,
        // as a uniform solid of that mass.
        let inertial = match (mass > 0.0, inertia == Mat3::ZERO && !collisions.is_empty()) {
            (false, _) => None,
            (true, true) => Some(solid_of(&collisions, mass)),
            (true, false) => Some(Inertial { origin: pose(&inertial.origin), mass, inertia, from_geometry: false }),
        };
        let visuals = link
            .visual
            .iter()
            .map(|v| {
                // Its own colour, else the named top-level material's, else neutral grey.
                let rgba = match &v.material {
                    Some(m) => match (&m.color, self.materials.get(&m.name)) {
                        (Some(c), _) => c.rgba.0.map(|x| x as f32),
                        (None, Some(named)) => *named,
                        (None, None) if m.name.is_empty() => [0.6, 0.6, 0.6, 1.0],
                        (None, None) => {
                            return Err(self.link_error(
                                &link.name,
                                format!("visual uses material '{}', which the robot does not define", m.name),
                            ));
                        }
                    },
                    None => [0.6, 0.6, 0.6, 1.0],
                };
                Ok(Visual { geometry: self.geometry(&link.name, &v.origin, &v.geometry)?, rgba })
            })
            .collect::<Result<_, _>>()?;
        Ok(LinkModel { name: link.name.clone(), inertial, collisions, visuals })
    }

    fn geometry(
        &self,
        link: &str,
        origin: &urdf_rs::Pose,
        geometry: &urdf_rs::Geometry,
    ) -> Result<Geometry, UrdfError> {
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v as f32)
            } else {
                Err(self.link_error(link, format!("{what} must be positive, got {v}")))
            }
        };
        let shape = match geometry {
            urdf_rs::Geometry::Box { size } => Shape::Box {
                half_extents: Vec3::new(
                    positive("box size x", size[0])?,
                    positive("box size y", size[1])?,
                    positive("box size z", size[2])?,
                ) / 2.0,
            },
            urdf_rs::Geometry::Cylinder { radius, length } => Shape::Cylinder {
                radius: positive("cylinder radius", *radius)?,
                length: positive("cylinder length", *length)?,
            },
            urdf_rs::Geometry::Sphere { radius } => Shape::Sphere { radius: positive("sphere radius", *radius)? },
            urdf_rs::Geometry::Capsule { .. } => {
                return Err(self.link_error(link, "capsule geometry is not supported"));
            }
            urdf_rs::Geometry::Mesh { filename, scale } => {
                let scale = scale.as_ref().map_or(Vec3::ONE, vec3);
                Shape::Mesh(Arc::new(self.mesh(link, filename, scale)?))
            }
        };
        Ok(Geometry { origin: pose(origin), shape })
    }

    fn mesh(&self, link: &str, filename: &str, scale: Vec3) -> Result<TriangleMesh, UrdfError> {
        let path = super::mesh::resolve_in(filename, self.mesh_dir, self.packages, &self.package_path)
            .map_err(|e| self.link_error(link, e))?;
        let (vertices, triangles) =
            super::mesh::read(&path).map_err(|e| self.link_error(link, format!("mesh '{filename}': {e}")))?;
        let vertices: Vec<Vec3> = vertices.into_iter().map(|v| v * scale).collect();
        // Collisions use the mesh's convex hull, so a flat or tiny mesh cannot be simulated.
        let hull = super::model::collision_hull(&vertices, self.max_hull_vertices)
            .filter(|hull| hull.mass_properties(1.0).mass() > 1e-12);
        let Some(hull) = hull else {
            return Err(self.link_error(
                link,
                format!("mesh file '{}' is degenerate (flat, or fewer than 4 distinct points)", path.display()),
            ));
        };
        Ok(TriangleMesh { vertices, triangles, hull })
    }

    fn joint(&self, joint: &urdf_rs::Joint, index: &HashMap<String, usize>) -> Result<JointModel, UrdfError> {
        let name = &joint.name;
        let kind = match &joint.joint_type {
            urdf_rs::JointType::Revolute => JointKind::Revolute,
            urdf_rs::JointType::Continuous => JointKind::Continuous,
            urdf_rs::JointType::Prismatic => JointKind::Prismatic,
            urdf_rs::JointType::Fixed => JointKind::Fixed,
            other => {
                return Err(self.joint_error(name, format!("joint type {other:?} is not supported")));
            }
        };
        let find = |role: &str, link: &str| {
            index
                .get(link)
                .copied()
                .ok_or_else(|| self.joint_error(name, format!("<{role} link=\"{link}\">: unknown link")))
        };
        let parent = find("parent", &joint.parent.link)?;
        let child = find("child", &joint.child.link)?;
        if parent == child {
            return Err(self.joint_error(name, format!("joins link '{}' to itself (a loop)", joint.child.link)));
        }
        let axis = vec3(&joint.axis.xyz);
        if kind.is_movable() && !(axis.length() > 1e-9) {
            return Err(self.joint_error(name, "<axis xyz> must not be zero"));
        }
        let limit = &joint.limit;
        let has_limit = self.lines.joints_with_limit.iter().any(|j| j == name);
        let bounded = matches!(kind, JointKind::Revolute | JointKind::Prismatic);
        if bounded && !has_limit {
            return Err(
                self.joint_error(name, "revolute and prismatic joints need <limit lower upper effort velocity>")
            );
        }
        let (lower, upper) = (limit.lower as f32, limit.upper as f32);
        if bounded && !(lower <= upper) {
            return Err(self.joint_error(name, format!("<limit> lower {lower} > upper {upper}")));
        }
        let (effort, velocity) = if has_limit { (limit.effort as f32, limit.velocity as f32) } else { (0.0, 0.0) };
        if !(effort >= 0.0 && velocity >= 0.0) {
            return Err(self.joint_error(name, "<limit> effort and velocity must be non-negative"));
        }
        Ok(JointModel {
            name: name.clone(),
            kind,
            parent,
            child,
            origin: pose(&joint.origin),
            axis: axis.normalize_or(Vec3::X),
            limits: JointLimits { position: bounded.then_some([lower, upper]), effort, velocity },
            damping: joint.dynamics.as_ref().map_or(0.0, |d| d.damping as f32),
            friction: joint.dynamics.as_ref().map_or(0.0, |d| d.friction as f32),
        })
    }
}

fn vec3(v: &urdf_rs::Vec3) -> Vec3 {
    Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32)
}

/// URDF `rpy` is roll about X, then pitch about Y, then yaw about Z, all about fixed axes.
fn pose(p: &urdf_rs::Pose) -> Pose {
    let [roll, pitch, yaw] = p.rpy.0.map(|a| a as f32);
    Pose::from_parts(vec3(&p.xyz), Quat::from_euler(EulerRot::ZYX, yaw, pitch, roll))
}
