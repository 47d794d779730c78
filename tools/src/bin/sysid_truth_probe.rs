//! Where does the UR5e's calibration fall short: in the search, or in the data? Records the
//! stand-in of `tests/logs/recovery.rs` (every fitted parameter off by up to ±30 %, a 12 ms
//! delay, 20 s of multisine with sensor noise), identifies it, then compares the tracking error
//! χ² at the fit with χ² at the truth, and for each parameter the change in χ² when it alone is
//! set to its truth. A truth below the fit means the minimum the search is after lies nearer the
//! truth than where it stopped; the error along the straight line between them shows whether
//! the way there falls or is flat to within the replay's numerical noise. `ROUNDS` > 1 restarts
//! the search from its last fit (new curvature, new CMA-ES state) that many times.
//!
//! `cargo run --release -p twinbots_tools --bin sysid_truth_probe -- [GENERATIONS] [ROUNDS]`

use anyhow::Context;
use twinbots_sim::Parameters;
use twinbots_sysid::excitation::Excitation;
use twinbots_sysid::identify::FitOptions;
use twinbots_sysid::{Recording, Rig, SensorNoise, identify, perturbed_truth, prepare, record};

fn main() -> anyhow::Result<()> {
    twinbots_learn::threads::configure();
    let args: Vec<String> = std::env::args().collect();
    let generations: usize = args.get(1).map_or(Ok(30), |s| s.parse()).context("GENERATIONS must be a whole number")?;
    let rounds: usize = args.get(2).map_or(Ok(1), |s| s.parse()).context("ROUNDS must be a whole number")?;
    let rig = Rig::of(&ur5e::robot())?;
    let truth = perturbed_truth(&rig);
    let recording =
        Recording { excitation: Excitation::Multisine, seconds: 20.0, seed: 1, noise: SensorNoise::default() };
    let log = prepare(&rig, &record(&rig, &truth, &recording)?, "fit")?;
    let logs = std::slice::from_ref(&log);
    let params: Vec<String> = rig.description.fit.iter().map(|s| s.to_string()).collect();
    let mut fit = identify(
        &rig,
        logs,
        &Parameters::default(),
        &FitOptions { params: params.clone(), popsize: 0, generations, seed: 3 },
        |_| {},
    )?;
    for round in 1..rounds {
        println!("round {round}: χ² {:.4} after {} candidates, {:.1} s", fit.cost_fitted, fit.candidates, fit.seconds);
        fit = identify(
            &rig,
            logs,
            &fit.values(),
            &FitOptions { params: params.clone(), popsize: 0, generations, seed: 3 + round as u64 },
            |_| {},
        )?;
    }
    let mut fitted = rig.nominal.clone();
    fitted.extend(&fit.values());
    let truth_full = rig.parameters(&truth)?;
    let chi2 = twinbots_sysid::search::costs(&rig, logs, &[truth_full.clone(), fitted.clone()]);
    println!(
        "χ² per step: truth {:.4}, fit {:.4} ({} candidates, {:.1} s; the replay's numerical noise ±{:.0} in χ² over {} samples)",
        chi2[0], chi2[1], fit.candidates, fit.seconds, fit.replay_noise, fit.samples
    );
    // The error on the straight line from the fit to the truth: a valley floor flat to within
    // the replay's noise shows as bumps, not a slope.
    let line: Vec<Parameters> = (0..=10)
        .map(|k| {
            let mut p = fitted.clone();
            for f in &fit.parameters {
                let (a, b) = (fitted.get(&f.name).unwrap_or(f.value), truth_full.get(&f.name).unwrap_or(f.value));
                p.0.insert(f.name.clone(), a + k as f64 / 10.0 * (b - a));
            }
            p
        })
        .collect();
    let along: Vec<String> =
        twinbots_sysid::search::costs(&rig, logs, &line).iter().map(|c| format!("{c:.4}")).collect();
    println!("χ² per step from the fit to the truth in tenths: {}", along.join(" "));
    for p in &fit.parameters {
        let t = truth.get(&p.name).unwrap_or(p.value);
        let mut one = fitted.clone();
        one.0.insert(p.name.clone(), t);
        let change = twinbots_sysid::search::costs(&rig, logs, &[one])[0] - chi2[1];
        let verdict = if p.not_identifiable.is_some() { "flagged" } else { "identified" };
        println!(
            "{:<28} truth {t:>9.4} fit {:>9.4} ({:+6.1} %) spread {:.1e}; χ² with it at its truth {change:+.4}; {verdict}",
            p.name,
            p.value,
            (p.value / t - 1.0) * 100.0,
            p.spread
        );
    }
    Ok(())
}
