//! `twinbots algos`: the learning algorithms of this build (`twinbots_learn::algos::ALGOS`).

/// The command's arguments (none).
#[derive(clap::Args)]
pub struct Args {}

/// `twinbots algos`.
pub fn exec(_args: Args) -> anyhow::Result<()> {
    for a in twinbots_learn::ALGOS {
        println!("{:<6} {}", a.name, a.summary);
    }
    Ok(())
}
