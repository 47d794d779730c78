//! The URDF loader fuzzed: the project's own URDFs and a robot of mesh files, mutated at random (numbers replaced by
//! hostile ones, lines deleted, duplicated or swapped, attribute values garbled, bytes inserted,
//! the text cut short), must each load or give an error naming the file, and never panic; each that
//! loads is spawned and stepped, and must stay finite.
//!
//! The suite runs 20,000 inputs; `TWINBOTS_URDF_FUZZ_CASES=1000000 cargo test --release --test
//! sim urdf_fuzz -- --nocapture` runs a million.

use std::path::Path;

use rand::{Rng, SeedableRng};
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{JointState, PhysicsSubstep, SimSettings, SpawnOptions};

/// Spawns `model` (base welded) and steps it 0.2 s: whether every joint state stays finite.
fn stands(model: &RobotModel) -> bool {
    let (mut app, _, spawned) = crate::common::robot_app(
        model,
        SpawnOptions { fixed_base: true, ..Default::default() },
        SimSettings::default(),
    );
    for _ in 0..50 {
        app.world_mut().run_schedule(PhysicsSubstep);
    }
    spawned
        .joints
        .values()
        .all(|&j| app.world().get::<JointState>(j).is_none_or(|s| s.position.is_finite() && s.velocity.is_finite()))
}

/// A robot of meshes as CAD tools export them — STL, OBJ and glTF, through `package://` and
/// relative paths, one link with a mass and no inertia — written to a scratch package.
fn mesh_robot() -> (std::path::PathBuf, String) {
    let root = std::env::temp_dir().join(format!("twinbots-fuzz-{}/mesh_description", std::process::id()));
    std::fs::create_dir_all(root.join("meshes")).unwrap();
    std::fs::create_dir_all(root.join("urdf")).unwrap();
    let tetra = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    std::fs::write(root.join("meshes/tetra.obj"), tetra).unwrap();
    let tri = |a: [f32; 3], b: [f32; 3], c: [f32; 3]| stl_io::Triangle {
        normal: stl_io::Normal::new([0.0, 0.0, 1.0]),
        vertices: [stl_io::Vertex::new(a), stl_io::Vertex::new(b), stl_io::Vertex::new(c)],
    };
    let (p0, p1, p2, p3) = ([0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]);
    let mut file = std::fs::File::create(root.join("meshes/tetra.stl")).unwrap();
    stl_io::write_stl(&mut file, [tri(p0, p2, p1), tri(p0, p1, p3), tri(p0, p3, p2), tri(p1, p2, p3)].iter()).unwrap();
    let text = r#"<robot name="meshes">
  <link name="base"><inertial><mass value="2"/></inertial>
    <visual><geometry><mesh filename="package://mesh_description/meshes/tetra.stl" scale="2 2 2"/></geometry></visual>
    <collision><geometry><mesh filename="package://mesh_description/meshes/tetra.stl" scale="2 2 2"/></geometry></collision></link>
  <link name="arm"><inertial><origin xyz="0 0 0.05"/><mass value="0.3"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial>
    <visual><geometry><mesh filename="../meshes/tetra.obj"/></geometry></visual>
    <collision><geometry><mesh filename="../meshes/tetra.obj"/></geometry></collision></link>
  <joint name="turn" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.2"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="5" velocity="1"/></joint>
</robot>
"#;
    let path = root.join("urdf/meshes.urdf");
    std::fs::write(&path, text).unwrap();
    (path, text.to_string())
}

const HOSTILE_NUMBERS: &[&str] = &[
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e39",
    "-1e39",
    "1e308",
    "-0",
    "0",
    "1e-45",
    "99999999999999999999",
    "",
    "abc",
    "1 2 3",
    "0x10",
    "--1",
    "1e",
    ".",
    "-",
    "3.4028236e38",
];
const INSERTS: &[&str] =
    &["<", ">", "\"", "&", "&amp;", "</link>", "<joint", "<!--", "]]>", "\u{0}", "é", "<limit effort=\"nan\"/>"];

fn mutate(text: &str, rng: &mut impl Rng) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for _ in 0..rng.random_range(1..=3) {
        if lines.is_empty() {
            break;
        }
        let i = rng.random_range(0..lines.len());
        match rng.random_range(0..7) {
            0 => lines[i] = replace_a_number(&lines[i], rng),
            1 => {
                lines.remove(i);
            }
            2 => {
                let copy = lines[i].clone();
                lines.insert(i, copy);
            }
            3 => {
                let j = rng.random_range(0..lines.len());
                lines.swap(i, j);
            }
            4 => lines[i] = garble_an_attribute(&lines[i], rng),
            5 => {
                let at = char_boundary(&lines[i], rng.random_range(0..=lines[i].len()));
                lines[i].insert_str(at, INSERTS[rng.random_range(0..INSERTS.len())]);
            }
            _ => {
                let at = char_boundary(&lines[i], rng.random_range(0..=lines[i].len()));
                lines[i].truncate(at);
                lines.truncate(i + 1);
            }
        }
    }
    lines.join("\n")
}

/// Whether an attribute value outside comments and the XML declaration holds a number that is not finite or beyond ±1e9.
fn has_hostile_number(text: &str) -> bool {
    let mut outside = text.to_string();
    for (open, close) in [("<!--", "-->"), ("<?", "?>")] {
        let mut rest = outside.as_str();
        let mut kept = String::new();
        while let Some(start) = rest.find(open) {
            kept += &rest[..start];
            rest = rest[start..].find(close).map_or("", |end| &rest[start + end + close.len()..]);
        }
        kept += rest;
        outside = kept;
    }
    // Only attributes the URDF schema reads as numbers (a garbled name is ignored by the loader).
    const NUMBERS: &[&str] = &[
        "xyz", "rpy", "size", "radius", "length", "value", "ixx", "ixy", "ixz", "iyy", "iyz", "izz", "effort",
        "velocity", "lower", "upper", "damping", "friction", "scale", "rgba",
    ];
    let pieces: Vec<&str> = outside.split("=\"").collect();
    pieces.windows(2).any(|pair| {
        let name = pair[0].rsplit(|c: char| c.is_whitespace() || c == '<').next().unwrap_or_default();
        let value = pair[1].split('"').next().unwrap_or_default();
        NUMBERS.contains(&name)
            && value.split_whitespace().filter_map(|t| t.parse::<f64>().ok()).any(|x| !x.is_finite() || x.abs() > 1e9)
    })
}

fn char_boundary(s: &str, mut at: usize) -> usize {
    while !s.is_char_boundary(at) {
        at -= 1;
    }
    at
}

/// One number in the line (a run of digits, signs, dots and exponents) replaced by a hostile one.
fn replace_a_number(line: &str, rng: &mut impl Rng) -> String {
    let starts: Vec<usize> = line.char_indices().filter(|(_, c)| c.is_ascii_digit()).map(|(i, _)| i).collect();
    if starts.is_empty() {
        return line.to_string();
    }
    let mut start = starts[rng.random_range(0..starts.len())];
    let bytes = line.as_bytes();
    let numeric = |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E');
    while start > 0 && numeric(bytes[start - 1]) {
        start -= 1;
    }
    let mut end = start;
    while end < bytes.len() && numeric(bytes[end]) {
        end += 1;
    }
    format!("{}{}{}", &line[..start], HOSTILE_NUMBERS[rng.random_range(0..HOSTILE_NUMBERS.len())], &line[end..])
}

/// The value of one attribute replaced by random printable characters.
fn garble_an_attribute(line: &str, rng: &mut impl Rng) -> String {
    let quotes: Vec<usize> = line.match_indices('"').map(|(i, _)| i).collect();
    if quotes.len() < 2 {
        return line.to_string();
    }
    let k = rng.random_range(0..quotes.len() / 2) * 2;
    let junk: String =
        (0..rng.random_range(0..12)).map(|_| rng.random_range(b' '..=b'~') as char).filter(|&c| c != '"').collect();
    format!("{}{}{}", &line[..=quotes[k]], junk, &line[quotes[k + 1]..])
}

#[test]
fn mutated_urdfs_load_or_name_their_file_and_never_panic() {
    let cases: usize = std::env::var("TWINBOTS_URDF_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000);
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/robots");
    let mut sources: Vec<(std::path::PathBuf, String)> = [
        "cartpole/cartpole.urdf",
        "pioneer3at/pioneer3at.urdf",
        "ur5e/ur5e.urdf",
        "../cells/part.urdf",
        "../cells/fixture.urdf",
    ]
    .iter()
    .map(|f| {
        let path = assets.join(f);
        let text = std::fs::read_to_string(&path).unwrap();
        (path, text)
    })
    .collect();
    sources.push(mesh_robot());
    // Hooks off: a caught panic is counted, not printed a million times.
    let previous_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
    let (mut loaded, mut refused, mut panics, mut hostile_loaded) = (0usize, 0usize, Vec::new(), Vec::new());
    let (mut spawned, mut unstable) = (0usize, Vec::new());
    let started = std::time::Instant::now();
    for case in 0..cases {
        let (path, text) = &sources[case % sources.len()];
        let input = mutate(text, &mut rng);
        let mesh_dir = path.parent().unwrap();
        match std::panic::catch_unwind(|| parse_urdf(&input, path, mesh_dir)) {
            Ok(Ok(model)) => {
                if has_hostile_number(&input) {
                    hostile_loaded.push(input);
                } else {
                    // What loads must build and step: no panic, no number lost.
                    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| stands(&model))) {
                        Ok(true) => spawned += 1,
                        Ok(false) => unstable.push(input),
                        Err(_) => panics.push(input),
                    }
                }
                loaded += 1
            }
            Ok(Err(e)) => {
                let message = e.to_string();
                assert!(
                    message.starts_with(&path.display().to_string()),
                    "an error that does not name its file: {message}"
                );
                refused += 1;
            }
            Err(_) => panics.push(input),
        }
    }
    std::panic::set_hook(previous_hook);
    eprintln!(
        "URDF fuzz: {cases} inputs in {:.1} s: {loaded} loaded ({spawned} of them spawned and stepped), {refused} refused with an error, {} panics",
        started.elapsed().as_secs_f64(),
        panics.len()
    );
    assert!(
        spawned > 0 && unstable.is_empty(),
        "{spawned} spawned; {} left the numbers, the first:\n{}",
        unstable.len(),
        unstable.first().map_or("", String::as_str)
    );
    assert!(panics.is_empty(), "{} inputs panicked the loader; the first:\n{}", panics.len(), panics[0]);
    assert!(
        hostile_loaded.is_empty(),
        "{} inputs with a non-finite or absurd number loaded; the first:\n{}",
        hostile_loaded.len(),
        hostile_loaded[0]
    );
    assert!(
        loaded > cases / 20 && refused > cases / 20,
        "{loaded} loaded, {refused} refused: the mutations are not a mix"
    );
}
