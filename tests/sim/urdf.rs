//! The URDF loader: each kind of bad input gets its own error naming file, line and element;
//! a valid URDF's numbers arrive in the components.

use std::path::{Path, PathBuf};

use twinbots_sim::urdf::{JointKind, Shape, UrdfError, load_urdf, parse_urdf};
use twinbots_sim::{Motor, SimSettings, SpawnOptions};

use crate::common::robot_app;

fn parse(text: &str) -> Result<twinbots_sim::urdf::RobotModel, UrdfError> {
    parse_urdf(text, Path::new("robots/bad.urdf"), Path::new("/nonexistent-mesh-dir"))
}

const LINK: &str =
    r#"<inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>"#;

fn robot(body: &str) -> String {
    format!("<robot name=\"t\">\n{}\n</robot>\n", body.replace("INERTIAL", LINK))
}

fn element_error(err: UrdfError) -> (u32, &'static str, String, String) {
    let text = err.to_string();
    assert!(text.starts_with("robots/bad.urdf:"), "error names the file: {text}");
    match err {
        UrdfError::Element { line, element, name, problem, .. } => (line, element, name, problem),
        other => panic!("expected an element error, got {other}"),
    }
}

#[test]
fn malformed_xml_names_file_and_position() {
    let err = parse("<robot name=\"t\">\n  <link name=\"a\">\n</robot>\n").unwrap_err();
    match &err {
        UrdfError::Xml { file, line, .. } => {
            assert_eq!(file, &PathBuf::from("robots/bad.urdf"));
            assert_eq!(*line, 3, "the mismatched closing tag is on line 3: {err}");
        }
        other => panic!("expected an XML error, got {other}"),
    }
}

#[test]
fn unknown_link_names_the_joint_and_its_line() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL</link>\n<link name=\"b\">INERTIAL</link>\n\
         <joint name=\"j\" type=\"fixed\"><parent link=\"a\"/><child link=\"nope\"/></joint>",
    ))
    .unwrap_err();
    let (line, element, name, problem) = element_error(err);
    assert_eq!((line, element, name.as_str()), (4, "joint", "j"));
    assert!(problem.contains("unknown link") && problem.contains("nope"), "{problem}");
}

#[test]
fn loop_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL</link>\n<link name=\"b\">INERTIAL</link>\n\
         <joint name=\"ab\" type=\"fixed\"><parent link=\"a\"/><child link=\"b\"/></joint>\n\
         <joint name=\"ba\" type=\"fixed\"><parent link=\"b\"/><child link=\"a\"/></joint>",
    ))
    .unwrap_err();
    let (_, element, _, problem) = element_error(err);
    assert_eq!(element, "joint");
    assert!(problem.contains("loop"), "{problem}");
}

#[test]
fn link_with_two_parents_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL</link>\n<link name=\"b\">INERTIAL</link>\n<link name=\"c\">INERTIAL</link>\n\
         <joint name=\"ac\" type=\"fixed\"><parent link=\"a\"/><child link=\"c\"/></joint>\n\
         <joint name=\"bc\" type=\"fixed\"><parent link=\"b\"/><child link=\"c\"/></joint>",
    ))
    .unwrap_err();
    let (line, element, name, problem) = element_error(err);
    assert_eq!((line, element, name.as_str()), (6, "joint", "bc"));
    assert!(problem.contains("two parents") && problem.contains("'ac'"), "{problem}");
}

#[test]
fn missing_mesh_file_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL<visual><geometry><mesh filename=\"meshes/arm.stl\"/></geometry></visual></link>",
    ))
    .unwrap_err();
    let (line, element, name, problem) = element_error(err);
    assert_eq!((line, element, name.as_str()), (2, "link", "a"));
    assert!(problem.contains("meshes/arm.stl") && problem.contains("not found"), "{problem}");
}

#[test]
fn negative_mass_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\"><inertial><mass value=\"-2\"/><inertia ixx=\"1\" ixy=\"0\" ixz=\"0\" iyy=\"1\" iyz=\"0\" izz=\"1\"/></inertial></link>",
    ))
    .unwrap_err();
    let (_, element, name, problem) = element_error(err);
    assert_eq!((element, name.as_str()), ("link", "a"));
    assert!(problem.contains("negative"), "{problem}");
}

#[test]
fn revolute_joint_without_limit_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL</link>\n<link name=\"b\">INERTIAL</link>\n\
         <joint name=\"j\" type=\"revolute\"><parent link=\"a\"/><child link=\"b\"/><axis xyz=\"0 0 1\"/></joint>",
    ))
    .unwrap_err();
    let (_, element, _, problem) = element_error(err);
    assert_eq!(element, "joint");
    assert!(problem.contains("<limit"), "{problem}");
}

#[test]
fn unreadable_file_names_the_path() {
    let err = load_urdf("/no/such/robot.urdf").unwrap_err();
    assert!(matches!(err, UrdfError::Io { .. }));
    assert!(err.to_string().contains("/no/such/robot.urdf"));
}

#[test]
fn stl_mesh_is_loaded_and_scaled() {
    let dir = std::env::temp_dir().join(format!("twinbots-stl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let v = |x: f32, y: f32, z: f32| stl_io::Vector::new([x, y, z]);
    let tri = |a, b, c| stl_io::Triangle { normal: v(0.0, 0.0, 0.0), vertices: [a, b, c] };
    let (p0, p1, p2, p3) = (v(0., 0., 0.), v(1., 0., 0.), v(0., 1., 0.), v(0., 0., 1.));
    let mesh = [tri(p0, p2, p1), tri(p0, p1, p3), tri(p0, p3, p2), tri(p1, p2, p3)];
    let mut file = std::fs::File::create(dir.join("tetra.stl")).unwrap();
    stl_io::write_stl(&mut file, mesh.iter()).unwrap();
    let text = robot(
        "<link name=\"a\">INERTIAL<collision><geometry><mesh filename=\"tetra.stl\" scale=\"2 2 2\"/></geometry></collision></link>",
    );
    let model = parse_urdf(&text, &dir.join("t.urdf"), &dir).unwrap();
    let Shape::Mesh(mesh) = &model.links[0].collisions[0].shape else { panic!("a mesh") };
    assert_eq!(mesh.triangles.len(), 4);
    assert!(mesh.vertices.iter().any(|p| (p.x - 2.0).abs() < 1e-6), "scale applied");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn cartpole_urdf_round_trips_into_components() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(cartpole::URDF_PATH);
    let model = load_urdf(&path).unwrap();
    let cart = &model.links[model.link_index("cart").unwrap()];
    assert_eq!(cart.inertial.unwrap().mass, 2.0);
    let pole = model.joint("pole_joint").unwrap();
    assert_eq!(pole.kind, JointKind::Revolute);
    assert_eq!(pole.limits.position, Some([-1.3, 1.3]));
    assert_eq!(pole.limits.effort, 0.0, "the pole hinge is passive");
    assert!((pole.axis - bevy::math::Vec3::Y).length() < 1e-6);
    let wheel = model.joint("wheel1_joint").unwrap();
    assert_eq!(wheel.kind, JointKind::Continuous);
    assert_eq!((wheel.limits.effort, wheel.limits.velocity), (10.0, 10.0));

    let (mut app, arena, spawned) = robot_app(&model, SpawnOptions::default(), SimSettings::default());
    app.update(); // rapier folds the mass properties in on the first step
    let world = app.world_mut();
    let motor = world.get::<Motor>(spawned.joint("wheel1_joint").unwrap()).unwrap();
    assert_eq!((motor.max_effort, motor.max_velocity), (10.0, 10.0));
    assert!(world.get::<Motor>(spawned.joint("pole_joint").unwrap()).is_none());
    assert!(spawned.joint("pole_tip_joint").is_none(), "fixed joints are welded, not simulated");
    // The pole body carries the pole and the tip ball welded to it: 0.22 kg.
    let pole_link = world.get::<twinbots_sim::Link>(spawned.link("pole").unwrap()).unwrap().body;
    let tip_link = world.get::<twinbots_sim::Link>(spawned.link("pole_tip").unwrap()).unwrap().body;
    assert_eq!(pole_link, tip_link);
    let mass = twinbots_sim::physics_in(world, arena).unwrap().bodies[pole_link].mass();
    assert!((mass - 0.22).abs() < 1e-5, "pole body mass {mass}");
}

#[test]
fn flat_stl_mesh_is_rejected() {
    let dir = std::env::temp_dir().join(format!("twinbots-flat-stl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let v = |x: f32, y: f32| stl_io::Vector::new([x, y, 0.0]);
    let flat = [stl_io::Triangle {
        normal: stl_io::Vector::new([0.0, 0.0, 1.0]),
        vertices: [v(0., 0.), v(1., 0.), v(0., 1.)],
    }];
    stl_io::write_stl(&mut std::fs::File::create(dir.join("flat.stl")).unwrap(), flat.iter()).unwrap();
    let text = robot(
        "<link name=\"a\">INERTIAL<collision><geometry><mesh filename=\"flat.stl\"/></geometry></collision></link>",
    );
    let err = parse_urdf(&text, &dir.join("t.urdf"), &dir).unwrap_err().to_string();
    assert!(err.contains("degenerate") && err.contains("<link name=\"a\">"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_visual_naming_an_undefined_material_is_rejected() {
    let err = parse(&robot(
        "<link name=\"a\">INERTIAL<visual><geometry><sphere radius=\"0.1\"/></geometry><material name=\"chrome\"/></visual></link>",
    ))
    .unwrap_err();
    let (_, element, _, problem) = element_error(err);
    assert_eq!(element, "link");
    assert!(problem.contains("'chrome'"), "{problem}");
}

#[test]
fn a_non_finite_or_absurd_number_names_its_line_element_and_attribute() {
    let text = robot(
        r#"<link name="base">
  <inertial><origin xyz="0 0 inf"/><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
</link>"#,
    );
    let (line, element, name, problem) = element_error(parse(&text).unwrap_err());
    assert_eq!((line, element, name.as_str()), (3, "link", "base"));
    assert!(problem.contains(r#"<origin xyz="0 0 inf">: inf is not a finite number"#), "{problem}");
    let text = robot(
        r#"<link name="base">INERTIAL<collision><geometry><box size="0.1 1e39 0.1"/></geometry></collision></link>"#,
    );
    let (_, _, _, problem) = element_error(parse(&text).unwrap_err());
    assert!(
        problem.contains("1000000000000000000000000000000000000000 is not a finite number") || problem.contains("1e39"),
        "{problem}"
    );
}

#[test]
fn the_urdf_check_lists_the_tree_stands_the_robot_and_flags_what_will_not_simulate_well() {
    let dir = std::env::temp_dir().join(format!("twinbots-urdf-check-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("flagged.urdf");
    std::fs::write(
        &path,
        r#"<robot name="flagged">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <link name="arm"><inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="stuck" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/><limit effort="5" velocity="0"/></joint>
</robot>"#,
    )
    .unwrap();
    let report = twinbots_sim::urdf::check::check(&path, 0.5, &[]).unwrap();
    assert_eq!(report.tree.len(), 3, "{:?}", report.tree);
    assert!(
        report.tree[1].contains("stuck (Revolute, range [0.000, 0.000], motor: effort 5 velocity 0) -> arm"),
        "{:?}",
        report.tree
    );
    let warnings = report.warnings.join("\n");
    assert!(warnings.contains("joint 'stuck' (Revolute) has no range"), "{warnings}");
    assert!(warnings.contains("joint 'stuck' has a motor but no speed limit"), "{warnings}");
    assert!(warnings.contains("link 'arm' has mass but no <collision>"), "{warnings}");
    assert_eq!(report.warnings.len(), 3, "{warnings}");
    assert!((report.seconds - 0.5).abs() < 1e-9 && report.fastest.0.is_finite());
    // The project's own arm stands without a warning.
    let ur5e = twinbots_sim::urdf::check::check(
        std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/robots/ur5e/ur5e.urdf")),
        0.5,
        &[],
    )
    .unwrap();
    assert!(ur5e.warnings.is_empty(), "{:?}", ur5e.warnings);
    let e = twinbots_sim::urdf::check::check(&path, 0.5, &["elbow".into()]).err().unwrap().to_string();
    assert!(e.contains("--decompose: robot 'flagged' has no link 'elbow' (its links: base, arm)"), "{e}");
}

#[test]
fn a_mass_without_inertia_takes_the_collision_geometrys() {
    // A 0.5 kg solid cylinder (r 4 cm, 50 cm long) lifted 25 cm, and a link whose inertia is given.
    let model = parse(&robot(
        r#"<link name="arm"><inertial><mass value="0.5"/></inertial>
             <collision><origin xyz="0 0 0.25"/><geometry><cylinder radius="0.04" length="0.5"/></geometry></collision></link>
           <link name="given">INERTIAL<collision><geometry><box size="1 1 1"/></geometry></collision></link>
           <joint name="j" type="fixed"><parent link="arm"/><child link="given"/></joint>"#,
    ))
    .unwrap();
    let arm = model.links[0].inertial.unwrap();
    assert!(arm.from_geometry);
    assert!((arm.origin.translation - bevy::math::Vec3::new(0.0, 0.0, 0.25)).length() < 1e-5, "{:?}", arm.origin);
    let (m, r, h) = (0.5f32, 0.04f32, 0.5f32);
    let across = m * (3.0 * r * r + h * h) / 12.0;
    let along = m * r * r / 2.0;
    let d = arm.inertia.to_cols_array();
    for (got, want) in [(d[0], across), (d[4], across), (d[8], along)] {
        assert!((got - want).abs() < 0.02 * want, "inertia diag {:?} vs {across} {across} {along}", [d[0], d[4], d[8]]);
    }
    let given = model.links[1].inertial.unwrap();
    assert!(!given.from_geometry && (given.inertia.to_cols_array()[0] - 0.1).abs() < 1e-6);
}

/// A U of three blocks as one OBJ mesh (0.6 m wide, 0.5 m high, a notch 0.4 m wide above a
/// 0.1 m floor): concave, as a nest or a bin is.
fn u_mesh(dir: &Path) -> PathBuf {
    let blocks = [
        ([-0.3, -0.2, 0.0], [0.3, 0.2, 0.1]),
        ([-0.3, -0.2, 0.1], [-0.2, 0.2, 0.5]),
        ([0.2, -0.2, 0.1], [0.3, 0.2, 0.5]),
    ];
    let mut obj = String::new();
    for (b, (lo, hi)) in blocks.iter().enumerate() {
        for k in 0..8 {
            let p = [
                if k & 1 == 0 { lo[0] } else { hi[0] },
                if k & 2 == 0 { lo[1] } else { hi[1] },
                if k & 4 == 0 { lo[2] } else { hi[2] },
            ];
            obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        }
        let o = b * 8 + 1;
        for [a, c, d, e] in [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]] {
            obj += &format!("f {} {} {} {}\n", o + a, o + c, o + d, o + e);
        }
    }
    let path = dir.join("u.obj");
    std::fs::write(&path, obj).unwrap();
    path
}

#[test]
fn a_decomposed_concave_mesh_lets_a_part_into_its_notch_where_its_hull_would_not() {
    let dir = std::env::temp_dir().join(format!("twinbots-decompose-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    u_mesh(&dir);
    let nest = parse_urdf(
        r#"<robot name="nest"><link name="nest"><inertial><mass value="5"/></inertial>
             <collision><geometry><mesh filename="u.obj"/></geometry></collision></link></robot>"#,
        &dir.join("nest.urdf"),
        &dir,
    )
    .unwrap();
    let part = crate::common::model_from(
        r#"<robot name="part"><link name="base"><inertial><mass value="0.5"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
             <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link></robot>"#,
    );
    let rest_height = |decompose: bool| {
        let options = SpawnOptions {
            fixed_base: true,
            environment: true,
            decompose: if decompose { vec!["nest".into()] } else { vec![] },
            ..Default::default()
        };
        let (mut app, arena, _) = robot_app(&nest, options, SimSettings::default());
        let dropped = SpawnOptions {
            base: twinbots_sim::rapier::prelude::Pose::from_translation(bevy::math::Vec3::new(0.0, 0.0, 0.9)),
            environment: true,
            ..Default::default()
        };
        let part = crate::common::spawn_into(&mut app, arena, &part, dropped);
        for _ in 0..60 {
            app.update();
        }
        let link = part.link("base").unwrap();
        crate::common::with_supervisor(&mut app, |s| s.link_state(link).unwrap().pose.translation.z)
    };
    let (hull, parts) = (rest_height(false), rest_height(true));
    assert!((hull - 0.55).abs() < 0.03, "on the hull's lid: {hull}");
    assert!((parts - 0.15).abs() < 0.03, "on the notch's floor: {parts}");
}

#[test]
fn a_dense_mesh_gets_a_sound_hull_of_256_vertices_and_too_large_a_one_is_not_split() {
    let dir = std::env::temp_dir().join(format!("twinbots-decompose-cap-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A binary STL of a sphere in rows × rows quads of two triangles: just over the cap.
    let rows = ((twinbots_sim::spawn::MAX_DECOMPOSED_TRIANGLES as f64 / 2.0).sqrt() as usize) + 1;
    let n = 2 * rows * rows;
    let point = |i: usize, j: usize| {
        let (theta, phi) =
            (std::f32::consts::PI * i as f32 / rows as f32, std::f32::consts::TAU * j as f32 / rows as f32);
        [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]
    };
    let mut stl = vec![0u8; 80];
    stl.extend((n as u32).to_le_bytes());
    for i in 0..rows {
        for j in 0..rows {
            let (a, b, c, d) = (point(i, j), point(i + 1, j), point(i + 1, j + 1), point(i, j + 1));
            for triangle in [[a, b, c], [a, c, d]] {
                stl.extend([0f32; 3].iter().chain(triangle.iter().flatten()).flat_map(|x| x.to_le_bytes()));
                stl.extend([0, 0]);
            }
        }
    }
    std::fs::write(dir.join("ball.stl"), stl).unwrap();
    let model = parse_urdf(
        r#"<robot name="ball"><link name="plate"><inertial><mass value="5"/></inertial>
             <collision><geometry><mesh filename="ball.stl"/></geometry></collision></link></robot>"#,
        &dir.join("ball.urdf"),
        &dir,
    )
    .unwrap();
    let check = |decompose: &[String]| {
        twinbots_sim::urdf::check::check_model(model.clone(), 0.0, decompose, &[], SimSettings::default())
    };
    let e = check(&["plate".into()]).err().unwrap().to_string();
    assert!(
        e.contains(&format!(
            "--decompose: link 'plate' has a collision mesh of {n} triangles, more than the {} a split",
            twinbots_sim::spawn::MAX_DECOMPOSED_TRIANGLES
        )),
        "{e}"
    );
    // As its convex hull (no split asked) the same mesh stands, its hull cut to 256 vertices and
    // sound: parry's own hull of these 100,000 points merges its faces away to no volume at all.
    assert!(check(&[]).is_ok());
    let twinbots_sim::urdf::Shape::Mesh(mesh) = &model.links[0].collisions[0].shape else { panic!() };
    let hull = mesh.hull.as_convex_polyhedron().unwrap();
    assert_eq!(hull.points().len(), twinbots_sim::urdf::MAX_HULL_VERTICES);
    let volume = mesh.hull.mass_properties(1.0).mass();
    let sphere = 4.0 / 3.0 * std::f32::consts::PI;
    assert!(volume > 0.97 * sphere && volume < sphere, "{volume} against the sphere's {sphere}");
    // A hull of fewer vertices than the cap is the mesh's own.
    let cube: Vec<bevy::math::Vec3> =
        (0..8).map(|k| bevy::math::Vec3::new((k & 1) as f32, (k >> 1 & 1) as f32, (k >> 2) as f32)).collect();
    let whole = twinbots_sim::urdf::collision_hull(&cube, 8).unwrap();
    assert_eq!(whole.as_convex_polyhedron().unwrap().points().len(), 8);
    assert!((whole.mass_properties(1.0).mass() - 1.0).abs() < 1e-5);
    std::fs::remove_dir_all(&dir).ok();
}
