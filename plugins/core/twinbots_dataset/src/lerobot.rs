//! Writing a LeRobotDataset v3.0 (LeRobot's `CODEBASE_VERSION = "v3.0"`, lerobot ≥ 0.4): episodes
//! of frames — the observed state, the action taken, the reward, whether the episode ended and
//! succeeded there, the episode's seed — in the dataset's files, which LeRobot, Hugging Face
//! `datasets`, pandas and any Parquet reader open:
//!
//! ```text
//! meta/info.json                                  the features, fps, counts, path templates
//! meta/stats.json                                 each feature's statistics over every frame
//! meta/tasks.parquet                              the tasks (their text is the index)
//! meta/episodes/chunk-000/file-000.parquet        one row per episode: its task, length, frames'
//!                                                 span, data file and statistics
//! data/chunk-000/file-000.parquet                 one row per frame (files of ≤ 100 MB)
//! ```
//!
//! Camera streams are image features (`observation.images.<camera>`, dtype `image`): each
//! frame's PNG in the data file, as LeRobot stores images when it records without video.
//!
//! The dataset is made in a directory beside `out` and renamed to it when whole: a killed
//! writer leaves no dataset, never half of one.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use twinbots_api::files::write_json;

use crate::stats::FeatureStats;
use crate::table::{Column, Table};

/// The format's version, as LeRobot checks it.
pub const CODEBASE_VERSION: &str = "v3.0";
/// LeRobot's defaults: files per chunk folder, and a data file's size before the next begins.
pub const CHUNKS_SIZE: usize = 1000;
pub const DATA_FILE_SIZE_MB: usize = 100;
const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";
const DATA_PATH: &str = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet";

/// What every frame of a dataset holds, beyond LeRobot's own indices.
#[derive(Clone, Debug)]
pub struct DatasetSpec {
    /// `robot_type` (the robot's name).
    pub robot: String,
    /// Frames a second (the control rate): a whole number where the rate is one.
    pub fps: f64,
    /// What each value of `observation.state` and of `action` is.
    pub state_names: Vec<String>,
    pub action_names: Vec<String>,
    /// The cameras whose images every frame holds, in [`Frame::images`]' order.
    pub cameras: Vec<CameraSpec>,
}

/// A camera stream: `observation.images.<name>`, RGB images of `width` × `height`.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSpec {
    pub name: String,
    pub width: u32,
    pub height: u32,
}

impl CameraSpec {
    /// Its feature's key.
    pub fn key(&self) -> String {
        format!("observation.images.{}", self.name)
    }
}

/// One control step: what was observed, what was done, and what followed.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub state: Vec<f32>,
    pub action: Vec<f32>,
    /// The reward the action earned (`next.reward`).
    pub reward: f32,
    /// Whether the episode ended after the action (`next.done`: terminated or truncated).
    pub done: bool,
    /// Whether it ended meeting its goal (`next.success`; true on a successful episode's last
    /// frame only).
    pub success: bool,
    /// Each camera's image of the observed state (PNG, RGB8 of the camera's size), in the
    /// spec's camera order.
    pub images: Vec<Vec<u8>>,
}

/// One episode: its task's text, the seed it started from, its frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    pub task: String,
    pub seed: u64,
    pub frames: Vec<Frame>,
}

/// What a written dataset holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Written {
    pub episodes: usize,
    pub frames: usize,
    pub data_files: usize,
}

/// Episodes gathered, then written as one LeRobotDataset at [`DatasetWriter::finish`].
pub struct DatasetWriter {
    out: PathBuf,
    spec: DatasetSpec,
    episodes: Vec<Episode>,
}

impl DatasetWriter {
    /// A dataset to be written at `out`, which must not exist yet.
    pub fn new(out: &Path, spec: DatasetSpec) -> anyhow::Result<Self> {
        anyhow::ensure!(!out.exists(), "{} exists: a dataset is written to a new directory", out.display());
        anyhow::ensure!(spec.fps.is_finite() && spec.fps > 0.0, "fps {} is not a rate", spec.fps);
        Ok(Self { out: out.to_path_buf(), spec, episodes: Vec::new() })
    }

    /// Adds an episode (at least one frame, of the spec's widths).
    pub fn add(&mut self, episode: Episode) -> anyhow::Result<()> {
        anyhow::ensure!(!episode.frames.is_empty(), "episode {} has no frames", self.episodes.len());
        for (k, f) in episode.frames.iter().enumerate() {
            anyhow::ensure!(
                f.state.len() == self.spec.state_names.len() && f.action.len() == self.spec.action_names.len(),
                "episode {}, frame {k}: {} state and {} action values, not {} and {}",
                self.episodes.len(),
                f.state.len(),
                f.action.len(),
                self.spec.state_names.len(),
                self.spec.action_names.len()
            );
            anyhow::ensure!(
                f.images.len() == self.spec.cameras.len() && f.images.iter().all(|png| png.starts_with(PNG_SIGNATURE)),
                "episode {}, frame {k}: {} images, not {} PNGs",
                self.episodes.len(),
                f.images.len(),
                self.spec.cameras.len()
            );
        }
        self.episodes.push(episode);
        Ok(())
    }

    pub fn episodes(&self) -> usize {
        self.episodes.len()
    }

    /// Writes the dataset; errors name the file.
    pub fn finish(self) -> anyhow::Result<Written> {
        anyhow::ensure!(!self.episodes.is_empty(), "no episodes to write");
        let staging = staging_dir(&self.out);
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| anyhow::anyhow!("{}: {e}", staging.display()))?;
        }
        let written = self.write(&staging).inspect_err(|_| {
            let _ = std::fs::remove_dir_all(&staging);
        })?;
        std::fs::rename(&staging, &self.out).map_err(|e| anyhow::anyhow!("{}: {e}", self.out.display()))?;
        Ok(written)
    }

    fn write(&self, root: &Path) -> anyhow::Result<Written> {
        let tasks = self.tasks();
        let frames: usize = self.episodes.iter().map(|e| e.frames.len()).sum();
        // Whole episodes per data file, a new file once the next would pass the size.
        let row_bytes = 4 * (self.spec.state_names.len() + self.spec.action_names.len()) + 4 * 2 + 8 * 5 + 2;
        let episode_bytes = |episode: &Episode| {
            episode.frames.iter().map(|f| row_bytes + f.images.iter().map(Vec::len).sum::<usize>()).sum::<usize>()
        };
        let mut files: Vec<Vec<usize>> = vec![Vec::new()];
        let mut bytes_in_file = 0;
        for (e, episode) in self.episodes.iter().enumerate() {
            let bytes = episode_bytes(episode);
            if bytes_in_file > 0 && bytes_in_file + bytes > DATA_FILE_SIZE_MB << 20 {
                files.push(Vec::new());
                bytes_in_file = 0;
            }
            files.last_mut().expect("one file at least").push(e);
            bytes_in_file += bytes;
        }
        let mut first_index = vec![0usize; self.episodes.len() + 1];
        for (e, episode) in self.episodes.iter().enumerate() {
            first_index[e + 1] = first_index[e] + episode.frames.len();
        }
        let mut data_file_of = vec![(0usize, 0usize); self.episodes.len()];
        for (n, members) in files.iter().enumerate() {
            let (chunk, file) = (n / CHUNKS_SIZE, n % CHUNKS_SIZE);
            let table = self.data_table(members, &first_index, &tasks);
            let path = root.join(chunk_file("data", chunk, file));
            create_parent(&path)?;
            table.write(&path).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
            for &e in members {
                data_file_of[e] = (chunk, file);
            }
        }
        let episode_stats: Vec<Vec<(String, FeatureStats)>> = (0..self.episodes.len())
            .map(|e| feature_stats(&self.data_table(&[e], &first_index, &tasks)))
            .collect::<anyhow::Result<_>>()?;
        let path = root.join(chunk_file("meta/episodes", 0, 0));
        create_parent(&path)?;
        self.episodes_table(&first_index, &data_file_of, &episode_stats)
            .write(&path)
            .map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
        let path = root.join("meta/tasks.parquet");
        tasks_table(&tasks).write(&path).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
        let all: Vec<usize> = (0..self.episodes.len()).collect();
        let stats: serde_json::Map<String, Value> = feature_stats(&self.data_table(&all, &first_index, &tasks))?
            .into_iter()
            .map(|(k, s)| (k, s.to_json()))
            .collect();
        write_json(&root.join("meta/stats.json"), &Value::Object(stats))?;
        write_json(&root.join("meta/info.json"), &self.info(frames, tasks.len()))?;
        Ok(Written { episodes: self.episodes.len(), frames, data_files: files.len() })
    }

    /// The tasks' texts in order of first appearance (their `task_index`).
    fn tasks(&self) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for e in &self.episodes {
            if !out.contains(&e.task) {
                out.push(e.task.clone());
            }
        }
        out
    }

    /// The features of `meta/info.json`, in the data files' column order.
    fn features(&self) -> Value {
        let scalar = |dtype: &str| json!({"dtype": dtype, "shape": [1], "names": null});
        let mut f = serde_json::Map::new();
        f.insert(
            "observation.state".into(),
            json!({"dtype": "float32", "shape": [self.spec.state_names.len()], "names": self.spec.state_names}),
        );
        f.insert(
            "action".into(),
            json!({"dtype": "float32", "shape": [self.spec.action_names.len()], "names": self.spec.action_names}),
        );
        for camera in &self.spec.cameras {
            f.insert(
                camera.key(),
                json!({"dtype": "image", "shape": [camera.height, camera.width, 3], "names": ["height", "width", "channels"]}),
            );
        }
        f.insert("next.reward".into(), scalar("float32"));
        f.insert("next.done".into(), scalar("bool"));
        f.insert("next.success".into(), scalar("bool"));
        f.insert("seed".into(), scalar("int64"));
        f.insert("timestamp".into(), scalar("float32"));
        for key in ["frame_index", "episode_index", "index", "task_index"] {
            f.insert(key.into(), scalar("int64"));
        }
        Value::Object(f)
    }

    fn info(&self, frames: usize, tasks: usize) -> Value {
        let fps = if self.spec.fps.fract() == 0.0 { json!(self.spec.fps as u64) } else { json!(self.spec.fps) };
        json!({
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.spec.robot,
            "total_episodes": self.episodes.len(),
            "total_frames": frames,
            "total_tasks": tasks,
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILE_SIZE_MB,
            "video_files_size_in_mb": 200,
            "fps": fps,
            "splits": {"train": format!("0:{}", self.episodes.len())},
            "data_path": DATA_PATH,
            "video_path": null,
            "features": self.features(),
        })
    }

    /// The frames of the episodes `members` as data-file columns.
    fn data_table(&self, members: &[usize], first_index: &[usize], tasks: &[String]) -> Table {
        let (sw, aw) = (self.spec.state_names.len(), self.spec.action_names.len());
        let (mut state, mut action, mut reward, mut done, mut success) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut seed, mut timestamp, mut frame_index, mut episode_index, mut index, mut task_index) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for &e in members {
            let episode = &self.episodes[e];
            let task = tasks.iter().position(|t| *t == episode.task).expect("the episode's task") as i64;
            for (k, f) in episode.frames.iter().enumerate() {
                state.extend_from_slice(&f.state);
                action.extend_from_slice(&f.action);
                reward.push(f.reward);
                done.push(f.done);
                success.push(f.success);
                seed.push(episode.seed as i64);
                timestamp.push((k as f64 / self.spec.fps) as f32);
                frame_index.push(k as i64);
                episode_index.push(e as i64);
                index.push((first_index[e] + k) as i64);
                task_index.push(task);
            }
        }
        let mut t = Table::default();
        t.push("observation.state", Column::F32Rows { width: sw, values: state });
        t.push("action", Column::F32Rows { width: aw, values: action });
        for (c, camera) in self.spec.cameras.iter().enumerate() {
            let frames = members.iter().flat_map(|&e| self.episodes[e].frames.iter().enumerate());
            let (png, paths) = frames.map(|(k, f)| (f.images[c].clone(), format!("frame-{k:06}.png"))).unzip();
            t.push(camera.key(), Column::Images { png, paths });
        }
        t.push("next.reward", Column::F32(reward));
        t.push("next.done", Column::Bool(done));
        t.push("next.success", Column::Bool(success));
        t.push("seed", Column::I64(seed));
        t.push("timestamp", Column::F32(timestamp));
        t.push("frame_index", Column::I64(frame_index));
        t.push("episode_index", Column::I64(episode_index));
        t.push("index", Column::I64(index));
        t.push("task_index", Column::I64(task_index));
        t.metadata.push(("huggingface".into(), huggingface_features(&t).to_string()));
        t
    }

    fn episodes_table(
        &self,
        first_index: &[usize],
        data_file_of: &[(usize, usize)],
        stats: &[Vec<(String, FeatureStats)>],
    ) -> Table {
        let n = self.episodes.len();
        let mut t = Table::default();
        t.push("episode_index", Column::I64((0..n as i64).collect()));
        t.push("tasks", Column::StrLists(self.episodes.iter().map(|e| vec![e.task.clone()]).collect()));
        t.push("length", Column::I64(self.episodes.iter().map(|e| e.frames.len() as i64).collect()));
        t.push("data/chunk_index", Column::I64(data_file_of.iter().map(|d| d.0 as i64).collect()));
        t.push("data/file_index", Column::I64(data_file_of.iter().map(|d| d.1 as i64).collect()));
        t.push("dataset_from_index", Column::I64(first_index[..n].iter().map(|&i| i as i64).collect()));
        t.push("dataset_to_index", Column::I64(first_index[1..].iter().map(|&i| i as i64).collect()));
        for (f, (feature, first)) in stats[0].iter().enumerate() {
            // Each episode's entries of this feature, once; then one column per statistic.
            let mut entries: Vec<_> = stats.iter().map(|episode| episode[f].1.entries().into_iter()).collect();
            for (key, _) in first.entries() {
                let values: Vec<Vec<f64>> =
                    entries.iter_mut().map(|e| e.next().expect("every episode has each statistic").1).collect();
                let column = match key {
                    _ if first.image => Column::F64Channels(values),
                    "min" | "max" if first.boolean => {
                        Column::BoolLists(values.iter().map(|v| v.iter().map(|&x| x > 0.5).collect()).collect())
                    }
                    _ => Column::F64Lists(values),
                };
                t.push(format!("stats/{feature}/{key}"), column);
            }
            t.push(
                format!("stats/{feature}/count"),
                Column::I64Lists(stats.iter().map(|e| vec![e[f].1.count as i64]).collect()),
            );
        }
        t.push("meta/episodes/chunk_index", Column::I64(vec![0; n]));
        t.push("meta/episodes/file_index", Column::I64(vec![0; n]));
        t
    }
}

/// The `huggingface` key Hugging Face `datasets` writes with a table: its features (fixed-length
/// lists as `List` with a `length`), so `datasets` reads the columns as LeRobot declares them.
fn huggingface_features(table: &Table) -> Value {
    let value = |dtype: &str| json!({"dtype": dtype, "_type": "Value"});
    let features: serde_json::Map<String, Value> = table
        .columns
        .iter()
        .filter_map(|(name, column)| {
            let feature = match column {
                Column::F32Rows { width, .. } => json!({"feature": value("float32"), "length": width, "_type": "List"}),
                Column::F32(_) => value("float32"),
                Column::I64(_) => value("int64"),
                Column::Bool(_) => value("bool"),
                Column::Str(_) => value("string"),
                Column::Images { .. } => json!({"_type": "Image"}),
                _ => return None,
            };
            Some((name.clone(), feature))
        })
        .collect();
    json!({"info": {"features": features}})
}

/// Every numeric column's statistics (booleans as 0 and 1; images per channel), by column name.
fn feature_stats(table: &Table) -> anyhow::Result<Vec<(String, FeatureStats)>> {
    let mut out = Vec::new();
    for (name, column) in &table.columns {
        let (values, width): (Vec<f64>, usize) = match column {
            Column::Images { png, .. } => {
                let decoded = png
                    .iter()
                    .map(|bytes| {
                        image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
                            .map(|i| i.into_rgb8().into_raw())
                    })
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|e| anyhow::anyhow!("{name}: an image that is no PNG: {e}"))?;
                out.push((name.clone(), FeatureStats::of_images(decoded.iter().map(Vec::as_slice))));
                continue;
            }
            Column::F32Rows { width, values } => (values.iter().map(|&v| f64::from(v)).collect(), *width),
            Column::F32(v) => (v.iter().map(|&v| f64::from(v)).collect(), 1),
            Column::I64(v) => (v.iter().map(|&v| v as f64).collect(), 1),
            Column::Bool(v) => (v.iter().map(|&v| f64::from(u8::from(v))).collect(), 1),
            _ => continue,
        };
        let mut stats = FeatureStats::of(&values, width);
        stats.boolean = matches!(column, Column::Bool(_));
        out.push((name.clone(), stats));
    }
    Ok(out)
}

/// `meta/tasks.parquet` as pandas writes a frame indexed by the tasks' texts (LeRobot reads it
/// with `pd.read_parquet` and looks tasks up in the index).
fn tasks_table(tasks: &[String]) -> Table {
    let mut t = Table::default();
    t.push("task_index", Column::I64((0..tasks.len() as i64).collect()));
    t.push("__index_level_0__", Column::Str(tasks.to_vec()));
    let pandas = json!({
        "index_columns": ["__index_level_0__"],
        "column_indexes": [{"name": null, "field_name": null, "pandas_type": "unicode", "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
        "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64", "metadata": null},
            {"name": null, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object", "metadata": null},
        ],
        "creator": {"library": "twinbots", "version": env!("CARGO_PKG_VERSION")},
        "pandas_version": "2.2.0",
    });
    t.metadata.push(("pandas".into(), pandas.to_string()));
    t
}

/// `dir/chunk-CCC/file-FFF.parquet`.
fn chunk_file(dir: &str, chunk: usize, file: usize) -> String {
    format!("{dir}/chunk-{chunk:03}/file-{file:03}.parquet")
}

/// Where a dataset bound for `out` is made.
fn staging_dir(out: &Path) -> PathBuf {
    let name = out.file_name().map_or_else(|| "dataset".into(), |n| n.to_string_lossy().to_string());
    out.with_file_name(format!(".{name}.partial"))
}

fn create_parent(path: &Path) -> anyhow::Result<()> {
    let dir = path.parent().expect("a file in the dataset");
    std::fs::create_dir_all(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))
}

#[cfg(test)]
mod tests;
