//! Off-screen frames of arena 0, from `twinbots_render` (as `twinbots capture` draws them).

use numpy::ndarray::Array3;
use twinbots_render::{Renderer, View};
use twinbots_task::AppVecEnv;

pub struct Frames {
    renderer: Renderer,
}

impl Frames {
    pub fn new(mut renderer: Renderer, view: View) -> Self {
        renderer.set_view(view);
        Self { renderer }
    }

    /// Arena 0 of `env` as it is now, `(height, width, 3)` RGB.
    pub fn render(&mut self, env: &mut AppVecEnv) -> anyhow::Result<Array3<u8>> {
        let arena = env.arenas()[0];
        self.renderer.sync(env.app_mut().world_mut(), arena);
        let rgb = self.renderer.render()?;
        let (w, h) = (self.renderer.width as usize, self.renderer.height as usize);
        Ok(Array3::from_shape_vec((h, w, 3), rgb)?)
    }
}
