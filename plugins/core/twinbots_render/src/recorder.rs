//! Frames of the twin as PNG files: `capture`'s and `eval --record`'s recorder. Frame `i` is
//! written right after physics step `i` (frame 0: the start), so it shows that step.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use twinbots_sim::Look;
use twinbots_task::AppVecEnv;

use crate::{Framing, Renderer, View};

/// A named camera of a cell framed by `framing` (a robot's `framing`).
pub fn camera(framing: &Framing, name: &str) -> anyhow::Result<View> {
    View::framed(framing, name)
        .ok_or_else(|| anyhow::anyhow!("unknown camera '{name}'; cameras: {}", Framing::CAMERAS.join(", ")))
}

/// `WxH` → (W, H).
pub fn parse_size(size: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = size.split_once('x').ok_or_else(|| anyhow::anyhow!("--size must look like 640x480, got '{size}'"))?;
    let w: u32 = w.parse().map_err(|_| anyhow::anyhow!("--size: bad width '{w}'"))?;
    let h: u32 = h.parse().map_err(|_| anyhow::anyhow!("--size: bad height '{h}'"))?;
    anyhow::ensure!(w > 0 && h > 0 && w <= 4096 && h <= 4096, "--size must be between 1x1 and 4096x4096");
    Ok((w, h))
}

/// Renders arena 0 of an env off-screen into numbered PNG frames (`capture`, `eval --record`,
/// `monitor --record`, `bench capture`).
pub struct Recorder {
    renderer: Renderer,
    out: PathBuf,
    pub written: usize,
    /// The look of the latest frame, when the arena has one (visual randomization).
    look: Option<Look>,
}

impl Recorder {
    pub fn new(size: (u32, u32), view: View, out: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
        let mut renderer = Renderer::new(size.0, size.1)?;
        renderer.set_view(view);
        Ok(Self { renderer, out: out.to_path_buf(), written: 0, look: None })
    }

    /// Lights cast shadows (before the first frame).
    pub fn with_shadows(mut self, shadows: bool) -> Self {
        self.renderer = self.renderer.with_shadows(shadows);
        self
    }

    /// Renders arena 0 of `env` as it is now into `frame_<step>.png`. A new look of the arena
    /// (visual randomization) is appended to `looks.jsonl` first: `{"frame": step, "look": …}`,
    /// in force from that frame on.
    pub fn frame(&mut self, env: &mut AppVecEnv, step: u64) -> anyhow::Result<PathBuf> {
        let arena = env.arenas()[0];
        let look = env.app().world().get::<Look>(arena);
        if look.is_some() && look != self.look.as_ref() {
            self.look = look.cloned();
            let line = serde_json::json!({ "frame": step, "look": self.look });
            let path = self.out.join("looks.jsonl");
            let mut file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .with_context(|| path.display().to_string())?;
            writeln!(file, "{line}").with_context(|| path.display().to_string())?;
        }
        self.renderer.sync(env.app_mut().world_mut(), arena);
        let rgb = self.renderer.render()?;
        let path = self.out.join(format!("frame_{step:05}.png"));
        image::save_buffer(&path, &rgb, self.renderer.width, self.renderer.height, image::ExtendedColorType::Rgb8)
            .with_context(|| path.display().to_string())?;
        self.written += 1;
        Ok(path)
    }
}
