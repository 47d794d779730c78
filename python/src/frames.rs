//! Off-screen frames of the arenas, from `twinbots_render` (as `twinbots capture` draws them):
//! arena 0 alone, or every arena in one frame (one tile each, read back once).

use numpy::ndarray::{Array3, Array4};
use twinbots_render::{Renderer, View};
use twinbots_task::AppVecEnv;

pub struct Frames {
    renderer: Renderer,
    view: View,
    /// Every arena at once: made on the first `render_all`.
    tiled: Option<Renderer>,
}

impl Frames {
    pub fn new(mut renderer: Renderer, view: View) -> Self {
        renderer.set_view(view);
        Self { renderer, view, tiled: None }
    }

    /// Arena 0 of `env` as it is now, `(height, width, 3)` RGB.
    pub fn render(&mut self, env: &mut AppVecEnv) -> anyhow::Result<Array3<u8>> {
        let arena = env.arenas()[0];
        self.renderer.sync(env.app_mut().world_mut(), arena);
        let rgb = self.renderer.render()?;
        let (w, h) = (self.renderer.width as usize, self.renderer.height as usize);
        Ok(Array3::from_shape_vec((h, w, 3), rgb)?)
    }

    /// Every arena of `env` as it is now, `(arenas, height, width, 3)` RGB, drawn in one frame.
    pub fn render_all(&mut self, env: &mut AppVecEnv) -> anyhow::Result<Array4<u8>> {
        let (w, h) = (self.renderer.width, self.renderer.height);
        let shots: Vec<_> = env.arenas().iter().map(|&a| (a, self.view)).collect();
        let tiled = match &mut self.tiled {
            Some(t) => t,
            None => self.tiled.insert(Renderer::tiled(w, h, shots.len())?),
        };
        let images = tiled.render_shots(env.app_mut().world_mut(), &shots)?;
        Ok(Array4::from_shape_vec((shots.len(), h as usize, w as usize, 3), images.concat())?)
    }
}
