//! Files written whole or not at all: every file twinbots writes goes through a temporary file
//! beside it and a rename, so a crash or a full disk never leaves a half-written file under the
//! final name (and a reader never sees one).

use std::io::Write;
use std::path::{Path, PathBuf};

/// The temporary path `path` is written through, beside it: `tmp` before its extension
/// (`plot.png` → `plot.tmp.png`), so that files of one stem (`model.json`,
/// `model.safetensors`) never share one, and a writer that picks its format by the extension
/// still finds it last.
pub fn temporary(path: &Path) -> PathBuf {
    match path.extension() {
        Some(extension) => path.with_extension(format!("tmp.{}", extension.to_string_lossy())),
        None => path.with_extension("tmp"),
    }
}

/// Writes `bytes` to `path` atomically, synced to disk before the rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = temporary(path);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}

/// Writes `value` as pretty JSON to `path` atomically; errors name the file.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    write_atomic(path, text.as_bytes()).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Has `write` make the file at the [`temporary`] path it is given (a writer that wants a path of
/// its own: an image encoder, safetensors), then moves it to `path`; errors name the file.
pub fn write_through(path: &Path, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let tmp = temporary(path);
    write(&tmp).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })?;
    std::fs::rename(&tmp, path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_is_replaced_whole_and_nothing_is_left_beside_it() {
        let dir = std::env::temp_dir().join(format!("twinbots-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.json");
        write_json(&path, &serde_json::json!({"x": 1})).unwrap();
        write_json(&path, &serde_json::json!({"x": 2})).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{\n  \"x\": 2\n}");
        let failed = write_through(&dir.join("b.png"), |tmp| {
            std::fs::write(tmp, b"half")?;
            anyhow::bail!("the encoder failed")
        });
        assert!(failed.is_err());
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left, vec![std::ffi::OsString::from("a.json")], "no temporary or partial file stays");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
