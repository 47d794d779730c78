//! The writer against what LeRobot reads: the parquet files, the JSON metadata, the statistics.

use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::record::Field;

use super::*;

fn spec() -> DatasetSpec {
    DatasetSpec {
        robot: "arm".into(),
        fps: 25.0,
        state_names: vec!["q".into(), "v".into()],
        action_names: vec!["u".into()],
        cameras: Vec::new(),
    }
}

fn episode(seed: u64, frames: usize) -> Episode {
    let frame = |k: usize| Frame {
        state: vec![k as f32, -(k as f32)],
        action: vec![0.5],
        reward: -1.0,
        done: k + 1 == frames,
        success: k + 1 == frames && seed == 3,
        images: Vec::new(),
    };
    Episode { task: "reach".into(), seed, frames: (0..frames).map(frame).collect() }
}

#[test]
fn the_data_file_holds_every_frame_with_its_episode_and_index() {
    let root = std::env::temp_dir().join(format!("twinbots-lerobot-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let out = root.join("dataset");
    std::fs::create_dir_all(&root).unwrap();
    let mut writer = DatasetWriter::new(&out, spec()).unwrap();
    writer.add(episode(3, 2)).unwrap();
    writer.add(episode(4, 3)).unwrap();
    assert!(writer.add(Episode { task: "reach".into(), seed: 5, frames: vec![] }).is_err());
    let wrong =
        Episode { frames: vec![Frame { state: vec![1.0], ..episode(5, 1).frames[0].clone() }], ..episode(5, 1) };
    assert!(writer.add(wrong).unwrap_err().to_string().contains("1 state and 1 action values, not 2 and 1"));
    assert_eq!(writer.finish().unwrap(), Written { episodes: 2, frames: 5, data_files: 1 });
    // Nothing left beside it but the dataset; writing again is refused.
    let names: Vec<_> = std::fs::read_dir(&root).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, vec![std::ffi::OsString::from("dataset")]);
    assert!(DatasetWriter::new(&out, spec()).is_err());

    let file = std::fs::File::open(out.join("data/chunk-000/file-000.parquet")).unwrap();
    let reader = SerializedFileReader::new(file).unwrap();
    let rows: Vec<Vec<(String, Field)>> = reader
        .get_row_iter(None)
        .unwrap()
        .map(|r| r.unwrap().get_column_iter().map(|(k, v)| (k.clone(), v.clone())).collect())
        .collect();
    assert_eq!(rows.len(), 5);
    let get = |row: usize, key: &str| rows[row].iter().find(|(k, _)| k == key).unwrap().1.clone();
    // Frame 1 of episode 1: index 3, seed 4, state [1, -1], at 0.04 s.
    assert_eq!(get(3, "index"), Field::Long(3));
    assert_eq!(get(3, "episode_index"), Field::Long(1));
    assert_eq!(get(3, "frame_index"), Field::Long(1));
    assert_eq!(get(3, "seed"), Field::Long(4));
    assert_eq!(get(3, "timestamp"), Field::Float(0.04));
    let Field::ListInternal(state) = get(3, "observation.state") else { panic!("a list") };
    assert_eq!(state.elements(), &[Field::Float(1.0), Field::Float(-1.0)]);
    assert_eq!((get(1, "next.done"), get(1, "next.success")), (Field::Bool(true), Field::Bool(true)));
    assert_eq!((get(4, "next.done"), get(4, "next.success")), (Field::Bool(true), Field::Bool(false)));
    let info: Value = serde_json::from_str(&std::fs::read_to_string(out.join("meta/info.json")).unwrap()).unwrap();
    assert_eq!((info["total_frames"].as_u64(), info["fps"].as_u64()), (Some(5), Some(25)));

    // The reader gives back every frame's state and action, in order.
    let demos = crate::read_demonstrations(&out, "observation.state", "action").unwrap();
    assert_eq!((demos.frames(), demos.episodes, demos.state_dim, demos.action_dim), (5, 2, 2, 1));
    assert_eq!(demos.states, vec![0.0, -0.0, 1.0, -1.0, 0.0, -0.0, 1.0, -1.0, 2.0, -2.0]);
    assert_eq!(demos.actions, vec![0.5; 5]);
    assert_eq!(demos.robot.as_deref(), Some("arm"));
    // A one-value feature read as a scalar column; a feature it lacks is named.
    assert_eq!(crate::read_demonstrations(&out, "observation.state", "next.reward").unwrap().actions, vec![-1.0; 5]);
    let err = crate::read_demonstrations(&out, "observation.images.top", "action").unwrap_err().to_string();
    assert!(err.contains("meta/info.json") && err.contains("no feature \"observation.images.top\""), "{err}");
    std::fs::remove_dir_all(&root).unwrap();
}

fn png(rgb: &[u8], width: u32, height: u32) -> Vec<u8> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .unwrap();
    out
}

#[test]
fn camera_streams_are_image_features_with_per_channel_statistics() {
    let root = std::env::temp_dir().join(format!("twinbots-lerobot-images-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let out = root.join("dataset");
    std::fs::create_dir_all(&root).unwrap();
    let spec = DatasetSpec { cameras: vec![CameraSpec { name: "side".into(), width: 2, height: 1 }], ..spec() };
    let mut writer = DatasetWriter::new(&out, spec).unwrap();
    // Red 0 then 255 in frame 0, 51 and 102 in frame 1; green 255, blue 0 throughout.
    let images = [png(&[0, 255, 0, 255, 255, 0], 2, 1), png(&[51, 255, 0, 102, 255, 0], 2, 1)];
    let mut episode = episode(3, 2);
    for (f, image) in episode.frames.iter_mut().zip(&images) {
        f.images = vec![image.clone()];
    }
    let mut bad = episode.clone();
    bad.frames[1].images = vec![b"not a png".to_vec()];
    assert!(writer.add(bad).unwrap_err().to_string().contains("frame 1: 1 images, not 1 PNGs"));
    writer.add(episode).unwrap();
    writer.finish().unwrap();

    let info: Value = serde_json::from_str(&std::fs::read_to_string(out.join("meta/info.json")).unwrap()).unwrap();
    let feature = &info["features"]["observation.images.side"];
    assert_eq!((feature["dtype"].as_str(), &feature["shape"]), (Some("image"), &json!([1, 2, 3])));
    let stats: Value = serde_json::from_str(&std::fs::read_to_string(out.join("meta/stats.json")).unwrap()).unwrap();
    let side = &stats["observation.images.side"];
    assert_eq!(
        (&side["min"], &side["max"], &side["count"]),
        (&json!([[[0.0]], [[1.0]], [[0.0]]]), &json!([[[1.0]], [[1.0]], [[0.0]]]), &json!([2]))
    );
    assert!((side["mean"][0][0][0].as_f64().unwrap() - 0.4).abs() < 1e-12, "{side}");

    // The data file: each frame's PNG as it was given, named as LeRobot names its frames.
    let file = std::fs::File::open(out.join("data/chunk-000/file-000.parquet")).unwrap();
    let reader = SerializedFileReader::new(file).unwrap();
    let rows: Vec<_> = reader.get_row_iter(None).unwrap().map(|r| r.unwrap()).collect();
    let side = |row: usize| {
        let (_, field) = rows[row].get_column_iter().find(|(k, _)| *k == "observation.images.side").unwrap();
        let Field::Group(group) = field else { panic!("a struct: {field:?}") };
        let fields: Vec<_> = group.get_column_iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        fields
    };
    let Field::Bytes(bytes) = &side(1)[0].1 else { panic!("bytes") };
    assert_eq!(bytes.data(), &images[1][..]);
    assert_eq!(side(1)[1], ("path".to_string(), Field::Str("frame-000001.png".into())));
    // The episodes' statistics of an image: per channel, as (3, 1, 1) lists.
    let file = std::fs::File::open(out.join("meta/episodes/chunk-000/file-000.parquet")).unwrap();
    let reader = SerializedFileReader::new(file).unwrap();
    let row = reader.get_row_iter(None).unwrap().next().unwrap().unwrap();
    let (_, max) = row.get_column_iter().find(|(k, _)| *k == "stats/observation.images.side/max").unwrap();
    // (Parquet's field display writes 0.0 as 0E0.)
    assert_eq!(format!("{max}"), "[[[1.0]], [[1.0]], [[0E0]]]");
    // Behaviour cloning reads the state and action beside the images.
    let demos = crate::read_demonstrations(&out, "observation.state", "action").unwrap();
    assert_eq!(demos.frames(), 2);
    std::fs::remove_dir_all(&root).unwrap();
}
