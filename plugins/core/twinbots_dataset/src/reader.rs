//! Reading the demonstrations of a LeRobot dataset (v3.0, and v2.x whose data files hold the
//! same columns): for every frame, in the dataset's order, the observed state and the action
//! taken — what behaviour cloning learns from. Any dataset in the format is read, twinbots'
//! or not: the features' widths come from `meta/info.json`, the frames from every Parquet file
//! under `data/` (their names sorted, as LeRobot numbers them), each file's rows as stored.

use std::fs::File;
use std::path::{Path, PathBuf};

use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::record::{Field, List};
use parquet::schema::types::Type;
use serde_json::Value;

/// The demonstrations of a dataset, as flat rows.
#[derive(Clone, Debug, PartialEq)]
pub struct Demonstrations {
    /// The dataset's directory.
    pub root: PathBuf,
    /// `robot_type` of `meta/info.json`, if it names one.
    pub robot: Option<String>,
    /// The features read: the observation's (`observation.state`) and the action's.
    pub state_key: String,
    pub action_key: String,
    pub state_dim: usize,
    pub action_dim: usize,
    /// `frames × state_dim` values, row-major.
    pub states: Vec<f32>,
    /// `frames × action_dim` values, row-major.
    pub actions: Vec<f32>,
    /// Distinct `episode_index` values met.
    pub episodes: usize,
}

impl Demonstrations {
    pub fn frames(&self) -> usize {
        self.states.len() / self.state_dim.max(1)
    }
}

/// Reads the frames' `state_key` and `action_key` features of the dataset at `root`. Errors
/// name the file, and the row and feature where one is at fault.
pub fn read_demonstrations(root: &Path, state_key: &str, action_key: &str) -> anyhow::Result<Demonstrations> {
    let info_path = root.join("meta/info.json");
    let text = std::fs::read_to_string(&info_path).map_err(|e| {
        anyhow::anyhow!(
            "{}: {e} (a LeRobot dataset has meta/info.json: `twinbots demos` writes one)",
            info_path.display()
        )
    })?;
    let info: Value = serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", info_path.display()))?;
    let version = info.get("codebase_version").and_then(Value::as_str).unwrap_or("");
    anyhow::ensure!(
        version.starts_with("v3.") || version.starts_with("v2."),
        "{}: codebase_version {version:?}: reads LeRobot datasets v2.x and v3.x",
        info_path.display()
    );
    let width = |key: &str| -> anyhow::Result<usize> {
        let feature = info.get("features").and_then(|f| f.get(key)).ok_or_else(|| {
            let known: Vec<&String> =
                info.get("features").and_then(Value::as_object).map(|f| f.keys().collect()).unwrap_or_default();
            anyhow::anyhow!("{}: no feature {key:?} (it has {known:?})", info_path.display())
        })?;
        let shape: Vec<u64> = feature
            .get("shape")
            .and_then(Value::as_array)
            .map(|s| s.iter().filter_map(Value::as_u64).collect())
            .unwrap_or_default();
        let dtype = feature.get("dtype").and_then(Value::as_str).unwrap_or("");
        anyhow::ensure!(
            matches!(dtype, "float32" | "float64" | "int64" | "int32"),
            "{}: feature {key:?} is {dtype:?}, not numbers (float32, float64, int64 or int32)",
            info_path.display()
        );
        anyhow::ensure!(
            shape.len() == 1 && shape[0] > 0,
            "{}: feature {key:?} has shape {shape:?}, not one axis of values",
            info_path.display()
        );
        Ok(shape[0] as usize)
    };
    let (state_dim, action_dim) = (width(state_key)?, width(action_key)?);
    let mut files = Vec::new();
    parquet_files(&root.join("data"), &mut files)?;
    files.sort();
    anyhow::ensure!(!files.is_empty(), "{}: no Parquet files", root.join("data").display());
    let mut out = Demonstrations {
        root: root.to_path_buf(),
        robot: info.get("robot_type").and_then(Value::as_str).map(str::to_string),
        state_key: state_key.to_string(),
        action_key: action_key.to_string(),
        state_dim,
        action_dim,
        states: Vec::new(),
        actions: Vec::new(),
        episodes: 0,
    };
    let mut episodes = std::collections::BTreeSet::new();
    for path in &files {
        read_file(path, &mut out, &mut episodes).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
    }
    out.episodes = episodes.len();
    anyhow::ensure!(out.frames() > 0, "{}: no frames", root.display());
    Ok(out)
}

fn parquet_files(dir: &Path, out: &mut Vec<PathBuf>) -> anyhow::Result<()> {
    let entries = std::fs::read_dir(dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry.map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?.path();
        if path.is_dir() {
            parquet_files(&path, out)?;
        } else if path.extension().is_some_and(|x| x == "parquet") {
            out.push(path);
        }
    }
    Ok(())
}

/// Appends one data file's frames.
fn read_file(
    path: &Path,
    out: &mut Demonstrations,
    episodes: &mut std::collections::BTreeSet<i64>,
) -> anyhow::Result<()> {
    let reader = SerializedFileReader::new(File::open(path)?)?;
    let schema = reader.metadata().file_metadata().schema();
    let keys = [out.state_key.as_str(), out.action_key.as_str(), "episode_index"];
    let mut fields = Vec::new();
    for key in keys {
        let field = schema.get_fields().iter().find(|f| f.name() == key).ok_or_else(|| {
            let known: Vec<&str> = schema.get_fields().iter().map(|f| f.name()).collect();
            anyhow::anyhow!("no column {key:?} (it has {known:?})")
        })?;
        fields.push(field.clone());
    }
    let projection = Type::group_type_builder(schema.name()).with_fields(fields).build()?;
    let base = out.frames();
    for (r, row) in reader.get_row_iter(Some(projection))?.enumerate() {
        let row = row?;
        for (name, field) in row.get_column_iter() {
            let at = || format!("row {r}, {name:?}");
            if name == "episode_index" {
                match field {
                    Field::Long(e) => episodes.insert(*e),
                    Field::Int(e) => episodes.insert(i64::from(*e)),
                    other => anyhow::bail!("{}: {other} is not an episode's index", at()),
                };
                continue;
            }
            let (dim, values) = if *name == out.state_key {
                (out.state_dim, &mut out.states)
            } else {
                (out.action_dim, &mut out.actions)
            };
            let before = values.len();
            match field {
                Field::ListInternal(list) => {
                    push_numbers(list, values).map_err(|e| anyhow::anyhow!("{}: {e}", at()))?
                }
                // A one-value feature stored as a scalar column.
                scalar => values.push(number(scalar).map_err(|e| anyhow::anyhow!("{}: {e}", at()))?),
            }
            anyhow::ensure!(
                values.len() - before == dim,
                "{}: {} values, not the {dim} of meta/info.json (frame {})",
                at(),
                values.len() - before,
                base + r
            );
        }
    }
    Ok(())
}

fn push_numbers(list: &List, values: &mut Vec<f32>) -> anyhow::Result<()> {
    for x in list.elements() {
        values.push(number(x)?);
    }
    Ok(())
}

fn number(field: &Field) -> anyhow::Result<f32> {
    let x = match field {
        Field::Float(x) => *x,
        Field::Double(x) => *x as f32,
        Field::Long(x) => *x as f32,
        Field::Int(x) => *x as f32,
        Field::Bool(b) => f32::from(u8::from(*b)),
        other => anyhow::bail!("{other} is not a number"),
    };
    anyhow::ensure!(x.is_finite(), "{x} is not a finite number");
    Ok(x)
}
