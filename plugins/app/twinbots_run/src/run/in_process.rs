//! A run trained in this process (design patterns 1 and 2): as DESIGN.md's data flow, the
//! learner runs on its own thread and steps the app through the crossbeam bridge; the Bevy app
//! runs on this thread, headless as fast as it can, or in a window that shows arena 0.

use std::time::Instant;

use twinbots_api::DesignPattern;
use twinbots_learn::run_dir::TimeBreakdown;
use twinbots_learn::{Learner, TrainingEnd};
use twinbots_render::viewer::TrainingView;
use twinbots_task::randomization::RandomizationPlugin;
use twinbots_task::{bridge, env};

use super::{Run, Watch, finish, panic_message};

impl Run {
    /// Trains the run on its arenas in this process until its budget or its solved criterion,
    /// then ends it ([`finish`]) and prints how it went. With `watch.window`, a window shows
    /// arena 0 while the other arenas train at full speed (closing it stops training); with
    /// `watch.live`, every arena is published to the live view.
    pub fn train(mut self, watch: Watch) -> anyhow::Result<()> {
        let view = watch.window;
        let pattern = self.settings.design_pattern()?;
        anyhow::ensure!(
            pattern != DesignPattern::Server,
            "design pattern 3 has no in-process env: use `twinbots serve` and `twinbots robot`"
        );
        let (settings, entry) = (&self.settings, &self.entry);
        let mut app = entry.app(settings.task.as_deref(), settings.arenas, settings.seed, pattern)?;
        settings.calibrate(&mut app);
        settings.observe(&mut app, entry, settings.arenas)?;
        app.add_plugins(bridge::BridgePlugin);
        if let Some(live) = watch.live {
            app.add_plugins(twinbots_live::LivePlugin(live));
        }
        settings.randomization.validate()?;
        if !settings.randomization.is_off() {
            app.add_plugins(RandomizationPlugin(settings.randomization.clone()));
        }
        let (_, spec) = env::start(&mut app)?;
        let mut channel_env = bridge::connect(app.world_mut())?;
        self.learner.check_spaces(&spec.observation_space, &spec.action_space)?;
        let title = format!(
            "{} — {}, pattern {}, {} arenas, seed {}",
            settings.robot,
            self.learner.algorithm(),
            settings.pattern,
            settings.arenas,
            settings.seed
        );
        let (mut callbacks, tally) = self.callbacks(title)?;
        self.truncate_if_resumed()?;
        let remaining = self.settings.timesteps.saturating_sub(self.learner.timesteps());
        let Run { settings, dir, entry, mut learner, .. } = self;

        // The learner's thread: the algorithm and its callbacks (logs, evaluations, checkpoints).
        let trainer = std::thread::spawn(move || -> anyhow::Result<(Box<dyn Learner>, TrainingEnd, f64)> {
            let started = Instant::now();
            let end = learner.learn(&mut channel_env, remaining, &mut callbacks)?;
            Ok((learner, end, started.elapsed().as_secs_f64()))
        });

        // The app's thread (this one): frames until the learner hangs up.
        let mut simulation_s = None;
        let sim = if view {
            // The window drives the app in time slices; closing the window stops training.
            let arena = app.world().resource::<env::ArenaOrder>().0[0];
            let source = TrainingView::new(app, arena);
            let shown = twinbots_render::viewer::run(
                Box::new(source),
                &format!("twinbots — training {}", settings.robot),
                entry.framing,
            );
            Ok(shown)
        } else {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| bridge::run_until_closed(&mut app)));
            simulation_s = app.world().get_resource::<bridge::SimulationTime>().map(|t| t.seconds);
            drop(app); // closes the bridge, so a learner still waiting gets an error rather than a hang
            r.map(Ok)
        };
        let learned =
            trainer.join().map_err(|p| anyhow::anyhow!("the trainer thread panicked: {}", panic_message(&p)))?;
        match sim {
            Err(p) => anyhow::bail!("the simulation panicked: {}", panic_message(&p)),
            Ok(Err(e)) => return Err(e),
            Ok(Ok(())) => {}
        }
        let (learner, end, wall) = learned?;
        tally.check()?;
        let times = learner.times();
        let model: &dyn twinbots_learn::Agent = learner.as_ref();
        let time = simulation_s.map(|sim| TimeBreakdown::new(&times, sim, wall));
        let (evaluation, summary) = finish(&settings, &dir, &entry, model, &end, wall, time)?;
        match end {
            TrainingEnd::Solved { timesteps, by } => {
                println!(
                    "solved ({by}) after {timesteps} steps in {wall:.1} s (mean of last 100 episodes {:.1})",
                    model.history().mean_score()
                )
            }
            _ if model.episodes() == 0 => println!("trained: {} steps in {wall:.1} s", model.timesteps()),
            _ => println!(
                "not solved: {} steps in {wall:.1} s, mean of last 100 episodes {:.1}",
                model.timesteps(),
                model.history().mean_score()
            ),
        }
        if let Some(time) = &summary.time_breakdown {
            println!("time: {}", time.describe());
        }
        println!("evaluation of the final model, {}", evaluation.describe());
        println!("run directory: {}", dir.path().display());
        Ok(())
    }
}
