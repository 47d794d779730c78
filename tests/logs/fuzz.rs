//! The readers of files users bring, fed damaged copies of good files: a UR recording (RTDE
//! CSV), a robot file and a Collada mesh. Each damaged input must give `Ok` or a clear `Err`,
//! never a panic, and finish. `TWINBOTS_FUZZ_INPUTS` sets how many per reader (CI: 20,000;
//! `TWINBOTS_FUZZ_INPUTS=1000000 cargo test --release --test logs fuzz -- --nocapture` for the
//! long run, docs/logs.md).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_log::rtde_csv::{self, Efforts};
use twinbots_sim::urdf::mesh::parse_collada;
use twinbots_sim::urdf::robot_file::RobotFile;

fn inputs() -> usize {
    std::env::var("TWINBOTS_FUZZ_INPUTS").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000)
}

/// Pieces a damaged file is likely to hold where a good one has numbers, names and markup.
const TOKENS: [&str; 16] =
    ["nan", "inf", "-1e309", "1e308", "-0", "\n", ",", " ", "\"", "<", ">", "/>", "]", "=", "\u{0}", "\u{1F916}"];

/// `seed` damaged by one to four random edits: a byte changed, a token inserted, a span cut or
/// doubled, the end cut off.
fn mutate(seed: &str, rng: &mut ChaCha8Rng) -> String {
    let mut bytes = seed.as_bytes().to_vec();
    for _ in 0..rng.random_range(1..=4) {
        let len = bytes.len().max(1);
        let at = rng.random_range(0..len).min(bytes.len());
        match rng.random_range(0..5) {
            0 if !bytes.is_empty() => {
                let i = at.min(bytes.len() - 1);
                bytes[i] = rng.random();
            }
            1 => {
                let token = TOKENS[rng.random_range(0..TOKENS.len())].as_bytes();
                bytes.splice(at..at, token.iter().copied());
            }
            2 => {
                let end = (at + rng.random_range(0..64)).min(bytes.len());
                bytes.drain(at..end);
            }
            3 => {
                let end = (at + rng.random_range(0..64)).min(bytes.len());
                let span = bytes[at..end].to_vec();
                bytes.splice(at..at, span);
            }
            _ => bytes.truncate(at),
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

/// Feeds `n` damaged copies of `seed` to `read`; returns how many it accepted. A panic fails,
/// naming the input.
fn fuzz(name: &str, seed: &str, n: usize, read: impl Fn(&str) -> bool) -> usize {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut accepted = 0;
    for k in 0..n {
        let input = mutate(seed, &mut rng);
        match catch_unwind(AssertUnwindSafe(|| read(&input))) {
            Ok(ok) => accepted += ok as usize,
            Err(_) => panic!("{name}: input {k} panicked the reader: {input:?}"),
        }
    }
    eprintln!("{name}: {n} damaged inputs, {accepted} accepted, the rest refused with an error, no panic");
    accepted
}

#[test]
fn damaged_files_get_errors_never_a_panic() {
    let n = inputs();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // A UR recording's header and first rows (the shared real UR5's, else one written here).
    let header = (["timestamp".to_string()].into_iter())
        .chain(
            ["target_q", "actual_q", "actual_qd", "target_moment", "actual_current"]
                .iter()
                .flat_map(|v| (0..6).map(move |j| format!("{v}_{j}"))),
        )
        .collect::<Vec<_>>()
        .join(" ");
    let rows: Vec<String> = (0..8)
        .map(|k| {
            let t = 0.008 * k as f64;
            std::iter::once(format!("{t}"))
                .chain((0..30).map(|j| format!("{:.6}", 0.1 * j as f64 + t)))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    let recording = format!("{header}\n{}\n", rows.join("\n"));
    assert!(rtde_csv::from_str(&recording, &Efforts::TargetMoment).is_ok());
    let efforts = Efforts::Current([10.0; 6]);
    fuzz("UR RTDE CSV", &recording, n, |text| rtde_csv::from_str(text, &efforts).is_ok());

    let robot_path = root.join("assets/robots/ur5.toml");
    let robot = std::fs::read_to_string(&robot_path).unwrap();
    assert!(RobotFile::parse(&robot, &robot_path).is_ok());
    fuzz("robot file", &robot, n, |text| RobotFile::parse(text, &robot_path).is_ok());

    let collada = r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="centimeter" meter="0.01"/><up_axis>Y_UP</up_axis></asset>
  <library_geometries><geometry id="sq"><mesh>
    <source id="p"><float_array id="pa" count="12">0 0 0 100 0 0 100 0 100 0 0 100</float_array>
      <technique_common><accessor source="#pa" count="4" stride="3"/></technique_common></source>
    <vertices id="v"><input semantic="POSITION" source="#p"/></vertices>
    <triangles count="2"><input semantic="VERTEX" source="#v" offset="0"/><p>0 1 2 0 2 3</p></triangles>
    <polylist count="1"><input semantic="VERTEX" source="#v" offset="0"/><vcount>4</vcount><p>0 1 2 3</p></polylist>
  </mesh></geometry></library_geometries>
  <library_nodes><node id="part"><instance_geometry url="#sq"/></node></library_nodes>
  <library_visual_scenes><visual_scene id="s">
    <node name="up"><translate>0 100 0</translate><rotate>0 0 1 90</rotate><scale>1 2 1</scale><instance_node url="#part"/></node>
    <node name="m"><matrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</matrix><node><instance_node url="#part"/></node></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>"##;
    assert!(parse_collada(collada).is_ok());
    fuzz("Collada", collada, n, |text| parse_collada(text).is_ok());
}
