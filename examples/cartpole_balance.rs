//! A hand-written feedback controller balances the cart-pole twin for a full episode (1950
//! steps) from a small initial tilt: proof that the twin is physically sane and controllable.
//! The controller is the robot's own classical one ([`cartpole::feedback`]).
//!
//! Run: `cargo run --release --example cartpole_balance [seed]`

use twinbots_api::VecEnv;
use twinbots_task::AppVecEnv;

fn main() {
    let seed = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    let mut env = AppVecEnv::new(cartpole::headless_app(1, seed));
    let mut obs = env.reset(Some(seed)).unwrap();
    println!("start: x {:+.3} m, pole {:+.3} rad", obs[0], obs[2]);
    let mut max_angle: f32 = 0.0;
    let mut max_x: f32 = 0.0;
    for step in 1..=2000 {
        let out = env.step(&cartpole::feedback(&obs)).unwrap();
        obs = out.obs;
        if let Some(last) = &out.final_obs[0] {
            let ep = out.episodes[0].as_ref().expect("finished episode has a summary");
            println!(
                "episode ended at step {step}: score {}, {} (last x {:+.3} m, pole {:+.3} rad)",
                ep.score,
                if out.truncated[0] { "truncated (balanced)" } else { "terminated (fell)" },
                last[0],
                last[2],
            );
            println!("largest |pole angle| {max_angle:.3} rad, largest |x| {max_x:.3} m");
            std::process::exit(if out.truncated[0] { 0 } else { 1 });
        }
        max_angle = max_angle.max(obs[2].abs());
        max_x = max_x.max(obs[0].abs());
    }
}
