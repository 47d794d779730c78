//! Known-truth recovery: record a stand-in robot whose physics are perturbed from the twin's,
//! then identify. Prints the recovered values; asserts what the fit must get right.

use twinbots_sim::Parameters;
use twinbots_sysid::excitation::Excitation;
use twinbots_sysid::identify::{FitOptions, position_rmse};
use twinbots_sysid::{Recording, Rig, SensorNoise, identify, perturbed_truth, prepare, record};

fn recording(excitation: Excitation, seconds: f64, seed: u64) -> Recording {
    Recording { excitation, seconds, seed, noise: SensorNoise::default() }
}

/// Fits `robot` to a multisine log of its perturbed truth and checks the fit on a chirp.
fn recover(
    robot: &twinbots_task::RobotDescription,
    seconds: f64,
    generations: usize,
) -> (Rig, Parameters, twinbots_sysid::Fit, f64, f64) {
    recover_truth(robot, perturbed_truth, seconds, generations)
}

/// [`recover`] from the hidden truth `truth` makes of the rig.
fn recover_truth(
    robot: &twinbots_task::RobotDescription,
    truth: impl Fn(&Rig) -> Parameters,
    seconds: f64,
    generations: usize,
) -> (Rig, Parameters, twinbots_sysid::Fit, f64, f64) {
    let rig = Rig::of(robot).unwrap();
    let truth = truth(&rig);
    let fit_log = record(&rig, &truth, &recording(Excitation::Multisine, seconds, 1)).unwrap();
    let held_out = record(&rig, &truth, &recording(Excitation::Chirp, seconds / 2.0, 2)).unwrap();
    let fit_log = prepare(&rig, &fit_log, "fit").unwrap();
    let held_out = prepare(&rig, &held_out, "held-out").unwrap();
    let params = rig.description.fit.iter().map(|s| s.to_string()).collect();
    let options = FitOptions { params, popsize: 0, generations, seed: 3 };
    let fit = identify(&rig, std::slice::from_ref(&fit_log), &Parameters::default(), &options, |_| {}).unwrap();
    let calibrated =
        rig.parameters(&twinbots_sysid::report::calibration_of(&fit, &Parameters::default()).parameters).unwrap();
    let before = position_rmse(&rig, std::slice::from_ref(&held_out), &rig.nominal, 0.05);
    let after = position_rmse(&rig, std::slice::from_ref(&held_out), &calibrated, 0.05);
    eprintln!(
        "{}: tracking error {:.3} -> {:.3} (replay noise ±{:.0} over {} samples); held-out position RMSE {before:.6} -> {after:.6}",
        rig.robot, fit.cost_nominal, fit.cost_fitted, fit.replay_noise, fit.samples
    );
    for p in &fit.parameters {
        let t = truth.get(&p.name).unwrap();
        let verdict = p.not_identifiable.as_deref().unwrap_or("identified");
        eprintln!(
            "  {:<30} truth {t:>10.5} fit {:>10.5} ({:+6.1} %) spread {:.1e}  {verdict}",
            p.name,
            p.value,
            (p.value / t - 1.0) * 100.0,
            p.spread
        );
    }
    (rig, truth, fit, before, after)
}

#[test]
fn ur5e_calibration_finds_the_delay_and_cuts_held_out_error() {
    let (rig, truth, fit, before, after) = recover(&ur5e::robot(), 20.0, 30);
    let delay = fit.parameters.iter().find(|p| p.name == "command_delay").unwrap();
    assert!((delay.value - 0.012).abs() < rig.dt(), "delay {} s, truth 0.012 s", delay.value);
    assert!(fit.cost_fitted < fit.cost_nominal * 0.01, "tracking error {} -> {}", fit.cost_nominal, fit.cost_fitted);
    assert!(after < before * 0.2, "held-out position RMSE {before} -> {after}: not an 80 % drop");
    // Every parameter within 10 % of its truth, or reported as not pinned down, with why.
    for p in &fit.parameters {
        let t = truth.get(&p.name).unwrap();
        assert!(
            (p.value / t - 1.0).abs() < 0.1 || p.not_identifiable.is_some(),
            "{}: {} vs truth {t}, reported identified",
            p.name,
            p.value
        );
    }
    assert!(fit.parameters.iter().all(|p| p.spread.is_finite() || p.not_identifiable.is_some()));
    // A floor, so that a fit that flags everything cannot pass: 13 of 19 land within 10 % of
    // their truth here (2026-12-06), as in the benchmark.
    let within = fit.parameters.iter().filter(|p| (p.value / truth.get(&p.name).unwrap() - 1.0).abs() < 0.1).count();
    assert!(within >= 10, "{within} of {} parameters within 10 % of their truth", fit.parameters.len());
}

/// Hidden truths the search was never tuned on: five drawn at random from the prior's ranges
/// (`random_truth`, seeds 1–5). Whatever each fit recovers, it never leaves the twin tracking the
/// fitting logs or a held-out log worse than the twin it started as, and it recovers most of the
/// parameters the logs can tell.
#[test]
fn random_truths_are_recovered_and_the_twin_is_never_made_worse() {
    // The five side by side: one fit leaves most of the second core idle.
    let fits: Vec<_> = std::thread::scope(|scope| {
        let runs: Vec<_> = (1..=5)
            .map(|seed| {
                scope.spawn(move || {
                    recover_truth(&ur5e::robot(), |rig| twinbots_sysid::random_truth(rig, seed), 20.0, 30)
                })
            })
            .collect();
        runs.into_iter().map(|run| run.join().expect("a fit panicked")).collect()
    });
    let mut recovered = Vec::new();
    for (seed, (_, truth, fit, before, after)) in (1..=5).zip(fits) {
        let within = |p: &twinbots_sysid::identify::Fitted| (p.value / truth.get(&p.name).unwrap() - 1.0).abs() < 0.15;
        let share = fit.parameters.iter().filter(|p| within(p)).count() as f64 / fit.parameters.len() as f64;
        eprintln!("truth {seed}: {:.0} % within 15 %, held-out RMSE {before:.6} -> {after:.6}", share * 100.0);
        recovered.push(share);
        match &fit.no_better {
            Some(why) => eprintln!("truth {seed}: {why}"),
            None => {
                assert!(fit.cost_fitted < fit.cost_nominal, "truth {seed}: the fit tracks the fitting log worse");
                assert!(after <= before, "truth {seed}: held-out position RMSE {before} -> {after}");
            }
        }
    }
    recovered.sort_by(f64::total_cmp);
    assert!(recovered[2] >= MEDIAN_RECOVERED, "median share within 15 %: {:?}", recovered);
}

/// The floor of the median share of parameters within 15 % of their truth over the five random
/// truths. Measured 2026-12-06: 74 % (14 of 19) for four truths, 68 % for one, median 74 %; the
/// search's start (the prior, 2^u from each truth) has about a fifth within 15 % by chance.
const MEDIAN_RECOVERED: f64 = 0.6;

#[test]
fn wheeled_robots_record_replay_and_identify() {
    for robot in [cartpole::robot(), pioneer3at::robot()] {
        let (rig, _, fit, _, _) = recover(&robot, 10.0, 6);
        let delay = fit.parameters.iter().find(|p| p.name == "command_delay").unwrap();
        assert!((delay.value - 0.012).abs() < rig.dt(), "{}: delay {} s, truth 0.012 s", rig.robot, delay.value);
        assert!(fit.cost_fitted <= fit.cost_nominal, "{}: the fit made the twin worse", rig.robot);
        // Their pendulums' replays diverge: what the fit cannot pin down, the report says.
        let truth = perturbed_truth(&rig);
        for p in fit.parameters.iter().filter(|p| p.name != "command_delay") {
            let t = truth.get(&p.name).unwrap();
            assert!(
                (p.value / t - 1.0).abs() < 0.1 || p.not_identifiable.is_some(),
                "{}: {} vs truth {t}, reported identified",
                p.name,
                p.value
            );
        }
    }
}

#[test]
fn same_seed_same_log_and_logs_replay_exactly_on_their_own_physics() {
    let rig = Rig::of(&ur5e::robot()).unwrap();
    let truth = perturbed_truth(&rig);
    let quiet = Recording {
        noise: SensorNoise { position: 0.0, velocity: 0.0, effort: 0.0 },
        ..recording(Excitation::Multisine, 2.0, 5)
    };
    let a = record(&rig, &truth, &quiet).unwrap();
    assert_eq!(a, record(&rig, &truth, &quiet).unwrap(), "same seed, same log");
    // Replayed on the very physics that recorded it, a noise-free log is matched exactly.
    let prepared = prepare(&rig, &a, "quiet").unwrap();
    let costs = twinbots_sysid::search::costs(
        &rig,
        std::slice::from_ref(&prepared),
        &[rig.parameters(&truth).unwrap(), rig.nominal.clone()],
    );
    assert!(costs[0] < 1e-6 * costs[1], "truth {} vs nominal {}", costs[0], costs[1]);
}

#[test]
fn residuals_square_to_the_tracking_error_and_a_gauss_newton_step_heads_for_the_truth() {
    use twinbots_sysid::replay::{residuals, tracking_cost};
    let rig = Rig::of(&ur5e::robot()).unwrap();
    let truth = perturbed_truth(&rig);
    let log =
        prepare(&rig, &record(&rig, &truth, &recording(Excitation::Multisine, 2.0, 7)).unwrap(), "short").unwrap();
    let logs = std::slice::from_ref(&log);
    // Where `identify`'s joint search starts: the prior, the delay found.
    let mut start = rig.parameters(&rig.description.prior_parameters()).unwrap();
    start.0.insert("command_delay".into(), 0.012);
    let bias = rig.biases(&start);
    let twin =
        twinbots_sysid::run(&rig, &log.start_positions(&rig, &start), &log.program, std::slice::from_ref(&start))
            .pop()
            .unwrap();
    let mut r = Vec::new();
    residuals(&log, &twin, &bias, &mut r);
    let total: f64 = tracking_cost(&log, &twin, &bias).iter().sum();
    assert!(
        (r.iter().map(|v| v * v).sum::<f64>() / total - 1.0).abs() < 1e-9,
        "Σr² {} vs χ² {total}",
        r.iter().map(|v| v * v).sum::<f64>()
    );
    // One Gauss–Newton step over every fitted parameter takes most of the error away.
    let names: Vec<String> = rig.description.fit.iter().map(|s| s.to_string()).collect();
    let specs = twinbots_sysid::identify::parameter_specs(&rig, &names).unwrap();
    let all: Vec<usize> = (0..specs.len()).collect();
    let (curvature, replays) = twinbots_sysid::sensitivity::gauss_newton(&rig, logs, &start, &specs, &all);
    assert_eq!(replays, specs.len() + 1);
    let step = curvature.newton_step().expect("every fitted parameter moves the replay");
    let mut moved = start.clone();
    for (spec, d) in specs.iter().zip(&step) {
        moved.0.insert(spec.name.clone(), (start.get(&spec.name).unwrap() + d).max(0.0));
    }
    let costs = twinbots_sysid::search::costs(&rig, logs, &[start.clone(), moved, rig.parameters(&truth).unwrap()]);
    eprintln!("χ² per step: start {:.3}, after one Gauss–Newton step {:.3}, truth {:.3}", costs[0], costs[1], costs[2]);
    assert!(costs[1] - costs[2] < 0.2 * (costs[0] - costs[2]), "{costs:?}");
}
