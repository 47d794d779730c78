//! Calibration: the parameter values whose replays track the logs best, found with CMA-ES
//! (fcmaes-core's ask/tell), one candidate per arena, all of a generation stepped side by side.

use std::time::Instant;

use serde::Serialize;
use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::{PreparedLog, compare};
use crate::rig::{Rig, run};
pub use crate::search::Generation;
use crate::search::{Basis, Block, Range, Search, blocks, costs};
use crate::uncertainty::{Spread, curvatures, spreads, whitened};

/// How a fit runs.
#[derive(Clone, Debug)]
pub struct FitOptions {
    /// The parameters to fit, by name.
    pub params: Vec<String>,
    /// Candidates per generation of the joints' search (0: CMA-ES's default, 4 + ⌊3 ln n⌋).
    pub popsize: usize,
    /// Generations at most.
    pub generations: usize,
    pub seed: u64,
}

/// One fitted parameter.
#[derive(Clone, Debug, Serialize)]
pub struct Fitted {
    pub name: String,
    pub unit: &'static str,
    pub nominal: f64,
    pub value: f64,
    /// Its standard deviation from the curvature of the tracking error around the fit, the
    /// other parameters of its joint free too (see `uncertainty`).
    pub spread: f64,
    /// Its standard deviation with the others held at the fit.
    pub conditional_spread: f64,
    /// `None` when identifiable, else why not.
    pub not_identifiable: Option<String>,
}

/// What a fit found.
#[derive(Clone, Debug, Serialize)]
pub struct Fit {
    pub robot: String,
    pub logs: Vec<String>,
    pub parameters: Vec<Fitted>,
    pub cost_nominal: f64,
    pub cost_fitted: f64,
    pub history: Vec<Generation>,
    pub candidates: usize,
    pub replays: usize,
    pub seconds: f64,
    /// Wall time per replay of one candidate over all fit logs (s).
    pub seconds_per_replay: f64,
    /// Samples (physics steps over all fit logs) the χ² sums over.
    pub samples: usize,
}

impl Fit {
    /// The fitted values.
    pub fn values(&self) -> Parameters {
        Parameters(self.parameters.iter().map(|p| (p.name.clone(), p.value)).collect())
    }
}

/// Checks a parameter list against the rig; the error names the unknown one and lists the known.
pub fn parameter_specs(rig: &Rig, names: &[String]) -> anyhow::Result<Vec<ParameterSpec>> {
    anyhow::ensure!(!names.is_empty(), "no parameters to fit");
    names
        .iter()
        .map(|name| {
            rig.catalogue.iter().find(|p| &p.name == name).cloned().ok_or_else(|| {
                let known: Vec<&str> = rig.catalogue.iter().map(|p| p.name.as_str()).collect();
                anyhow::anyhow!("unknown parameter '{name}' for robot '{}'; known: {}", rig.robot, known.join(", "))
            })
        })
        .collect()
}

/// A spread `s` in the unit box at `u`, in the parameter's units (the wider side).
fn searched_spread(range: &Range, u: f64, s: f64) -> f64 {
    (range.value((u + s).min(1.0)) - range.value(u)).abs().max((range.value(u) - range.value((u - s).max(0.0))).abs())
}

/// How finely a parameter at `value` is to be known: within 10 % of its value at two standard
/// deviations (a delay: within a physics step; a bias: within 2 mrad or mm).
fn resolution(spec: &ParameterSpec, value: f64, dt: f64) -> f64 {
    match spec.kind {
        ParameterKind::CommandDelay => dt / 2.0,
        ParameterKind::Bias => 1e-3,
        _ => 0.05 * value.abs(),
    }
}

/// Mean position RMSE over `logs` of the twin with `params`.
pub fn position_rmse(rig: &Rig, logs: &[PreparedLog], params: &Parameters, threshold: f64) -> f64 {
    let bias = rig.biases(params);
    let sum: f64 = logs
        .iter()
        .map(|log| {
            let twin = run(rig, &log.start_positions(rig, params), &log.program, std::slice::from_ref(params)).pop().expect("one arena");
            compare(rig, log, &twin, &bias, threshold).position_rmse
        })
        .sum();
    sum / logs.len().max(1) as f64
}

/// Fits `options.params` of the twin (over `base`, the parameters not fitted) to `logs`,
/// calling `progress` after every generation.
pub fn identify(rig: &Rig, logs: &[PreparedLog], base: &Parameters, options: &FitOptions, mut progress: impl FnMut(&Generation)) -> anyhow::Result<Fit> {
    anyhow::ensure!(!logs.is_empty(), "no logs to fit");
    let specs = parameter_specs(rig, &options.params)?;
    // The twin as it runs (what "nominal" compares against), and where the search starts: the
    // robot's prior over it, then the given calibration's values.
    let twin = rig.parameters(base)?;
    let mut start = rig.description.prior_parameters();
    start.extend(base);
    let base = rig.parameters(&start)?;
    let ranges: Vec<Range> = specs
        .iter()
        .map(|s| Range::of(&ParameterSpec { default: rig.value(&base, &s.name), ..s.clone() }, rig.dt()))
        .collect();
    let search = Search { rig, logs, specs: &specs, ranges: &ranges, base: &base, seed: options.seed };
    let started = Instant::now();
    let mut u: Vec<f64> = specs.iter().zip(&ranges).map(|(s, r)| r.unit(rig.value(&base, &s.name))).collect();
    let cost_nominal = costs(rig, logs, std::slice::from_ref(&twin))[0];
    let blocks = blocks(rig, &specs);
    let (global, joints): (Vec<Block>, Vec<Block>) = blocks.iter().cloned().partition(|b| b.joint.is_none());
    // The parameters of no joint (the delay), and all the joints' ones.
    let global: Vec<usize> = global.iter().flat_map(|b| b.members.clone()).collect();
    let members: Vec<usize> = joints.iter().flat_map(|b| b.members.clone()).collect();
    let mut history = Vec::new();
    let mut candidates = 1;
    // CMA-ES's own default, 4 + ⌊3 ln n⌋ (12 for the UR5e's 18 joint parameters).
    let popsize = if options.popsize > 0 { options.popsize } else { 4 + (3.0 * (members.len().max(1) as f64).ln()).floor() as usize };
    let samples: usize = logs.iter().map(|l| l.reference.len()).sum();
    // A search along the delay (or a bias) may stop once its generation spreads less than a
    // half of what the delay must be known to; the joints' search runs its generations
    // (their spread is checked after, against their resolution).
    let settled: Vec<f64> = specs
        .iter()
        .zip(&ranges)
        .map(|(spec, range)| match spec.kind {
            ParameterKind::CommandDelay | ParameterKind::Bias => {
                let value = rig.value(&base, &spec.name);
                range.unit_spread(value, resolution(spec, value, rig.dt()) / 2.0)
            }
            _ => 2e-3,
        })
        .collect();
    let mut extra = 0;
    // The joints' search's last spread per parameter (unit box): 0 where it was not searched.
    let mut unsettled = vec![0.0; specs.len()];
    let g = options.generations;
    // 1. The delay alone, the rest nominal: it moves every joint, and it is 1-D.
    candidates += search.evolve(&mut u, &global, &Basis::diagonal(&vec![0.1; global.len()]), &settled, (g / 2).max(10), 6, &mut history, &mut progress).0;
    // 2. Every joint's parameters as one search scored by the total error (a joint's
    //    parameters reach the other joints' errors too), in coordinates whitened by the
    //    error's curvature at stage 1's fit, per joint (`uncertainty::whitened`): a joint's
    //    damping and friction trade off, and the parameters act at scales orders apart, which
    //    a search started round would first have to learn over many generations.
    if !members.is_empty() && g > 0 {
        let (curvatures, probes) = curvatures(rig, logs, &search.set(&u), &specs, &joints);
        extra += probes;
        let basis = whitened(&curvatures, &joints, &members, &ranges, &u, samples, 10.0, (1e-4, 0.1, 0.1));
        let (n, spread) = search.evolve(&mut u, &members, &basis, &settled, g, popsize, &mut history, &mut progress);
        candidates += n;
        unsettled = spread;
    }
    // 3. The delay again, at the joints' fit.
    if g >= 4 {
        // Near its fit already: small first steps.
        candidates += search.evolve(&mut u, &global, &Basis::diagonal(&vec![0.02; global.len()]), &settled, g / 4, 6, &mut history, &mut progress).0;
    }
    candidates += extra;
    let fitted = search.set(&u);
    let best = costs(rig, logs, std::slice::from_ref(&fitted))[0];
    candidates += 1;
    let seconds_fit = started.elapsed().as_secs_f64();
    let replays = 1 + candidates;
    let (spreads, replays_spread) = spreads(rig, logs, &fitted, &specs, &blocks, samples);
    let spreads: Vec<Spread> = spreads.into_iter().map(|s| s.expect("every fitted parameter is in a block")).collect();
    let parameters = specs
        .iter()
        .zip(&ranges)
        .zip(&u)
        .zip(&spreads)
        .enumerate()
        .map(|(i, (((spec, range), &u), spread))| {
            let value = range.value(u);
            let at_bound = u <= 1e-3 || u >= 1.0 - 1e-3;
            let resolution = resolution(spec, value, rig.dt());
            let not_identifiable = if spread.offset.abs() > resolution {
                Some(format!(
                    "the search had not settled along it: the error still falls towards {:.4e} (its curvature puts the minimum {:+.2e} {} away)",
                    value + spread.offset,
                    spread.offset,
                    spec.unit
                ))
            } else if let Some(last) = Some(searched_spread(range, u, unsettled[i])).filter(|s| *s > resolution) {
                Some(format!("the search had not settled along it: its last generation still spread ±{last:.2e} {}", spec.unit))
            } else if spread.conditional > resolution {
                Some(format!(
                    "the logs' motion barely exercises it: ±{:.3e} {} changes the tracking error by only Δχ² = {:.1} over {samples} samples",
                    spread.probe,
                    spec.unit,
                    (spread.probe / spread.conditional).powi(2),
                ))
            } else if spread.marginal > resolution {
                let partner = spread.partner.map_or("another parameter".to_string(), |(q, r)| format!("{} (correlation {r:+.2})", specs[q].name));
                Some(format!("it trades off against {partner}: the logs' motion does not tell them apart (spread {:.2e})", spread.marginal))
            } else if at_bound {
                Some(format!("the fit ran into the edge of its search range [{:.4e}, {:.4e}]", range.lo, range.hi))
            } else {
                None
            };
            let nominal = rig.value(&rig.nominal, &spec.name);
            Fitted { name: spec.name.clone(), unit: spec.unit, nominal, value, spread: spread.marginal, conditional_spread: spread.conditional, not_identifiable }
        })
        .collect();
    Ok(Fit {
        robot: rig.robot.to_string(),
        logs: logs.iter().map(|l| l.name.clone()).collect(),
        parameters,
        cost_nominal,
        cost_fitted: best,
        history,
        candidates,
        replays: replays + replays_spread,
        seconds: started.elapsed().as_secs_f64(),
        seconds_per_replay: seconds_fit / replays as f64,
        samples,
    })
}

