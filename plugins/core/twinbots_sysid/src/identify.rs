//! Calibration: the parameter values whose replays track the logs best, found with CMA-ES
//! (fcmaes-core's ask/tell), one candidate per arena, all of a generation stepped side by side.

use std::time::Instant;

use serde::Serialize;
use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::{PreparedLog, compare};
use crate::rig::{Rig, run};
pub use crate::search::Generation;
use crate::search::{Basis, Block, Range, Search, blocks, costs};
use crate::sensitivity::gauss_newton;
use crate::uncertainty::{spreads, whitened};

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
    /// Its standard deviation from the curvature of the tracking error around the fit, every
    /// other fitted parameter free too, widened for the replay's numerical noise (see
    /// `uncertainty`).
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
    /// χ² per step of the twin as it runs (the robot's nominal parameters with the given
    /// calibration over them), of where the search started (the prior with the calibration over
    /// it), and of the fit.
    pub cost_nominal: f64,
    pub cost_start: f64,
    pub cost_fitted: f64,
    /// Why the fit is no improvement, when it tracks the logs no better than the twin as it runs
    /// or the search's start: then it must not be written.
    pub no_better: Option<String>,
    pub history: Vec<Generation>,
    pub candidates: usize,
    pub replays: usize,
    pub seconds: f64,
    /// Wall time per replay of one candidate over all fit logs (s).
    pub seconds_per_replay: f64,
    /// Samples (physics steps over all fit logs) the χ² sums over.
    pub samples: usize,
    /// The replay's own numerical noise at the fit, in total χ² (`uncertainty::Uncertainty`):
    /// above 1, the spreads are widened by its square root.
    pub replay_noise: f64,
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

/// How many times the χ² of a twin that matches the logs to their noise a fit may score and
/// still be read by its spreads (the UR5e's fits score 0.5–0.8 times; the cart-pole's and the
/// Pioneer's, whose free pendulums' replays diverge, 4–5 times).
const MISFIT: f64 = 3.0;

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
            let twin = run(rig, &log.start_positions(rig, params), &log.program, std::slice::from_ref(params))
                .pop()
                .expect("one arena");
            compare(rig, log, &twin, &bias, threshold).position_rmse
        })
        .sum();
    sum / logs.len().max(1) as f64
}

/// Fits `options.params` of the twin (over `base`, the parameters not fitted) to `logs`,
/// calling `progress` after every generation.
pub fn identify(
    rig: &Rig,
    logs: &[PreparedLog],
    base: &Parameters,
    options: &FitOptions,
    mut progress: impl FnMut(&Generation),
) -> anyhow::Result<Fit> {
    anyhow::ensure!(!logs.is_empty(), "no logs to fit");
    let specs = parameter_specs(rig, &options.params)?;
    // The twin as it runs (what "nominal" compares against), and where the search starts: the
    // twin with the robot's prior for each fitted parameter the given calibration does not set.
    // The parameters not fitted stay as the twin has them: the fit is scored with the values
    // its calibration file will run with.
    let twin = rig.parameters(base)?;
    let prior = rig.description.prior_parameters();
    let mut start = twin.clone();
    for spec in specs.iter().filter(|s| base.get(&s.name).is_none()) {
        start.0.insert(spec.name.clone(), rig.value(&prior, &spec.name));
    }
    let base = rig.parameters(&start)?;
    let ranges: Vec<Range> = specs
        .iter()
        .map(|s| Range::of(&ParameterSpec { default: rig.value(&base, &s.name), ..s.clone() }, rig.dt()))
        .collect();
    let search = Search { rig, logs, specs: &specs, ranges: &ranges, base: &base, seed: options.seed };
    let started = Instant::now();
    let cost_nominal = costs(rig, logs, std::slice::from_ref(&twin))[0];
    let cost_start = if twin == base { cost_nominal } else { costs(rig, logs, std::slice::from_ref(&base))[0] };
    let samples: usize = logs.iter().map(|l| l.reference.len()).sum();
    let plan = Plan::of(rig, &specs, &ranges, &base, options);
    let mut history = Vec::new();
    // From the prior (with the given calibration over it); where that strands the search worse
    // than the twin as it runs, again from the twin as it runs.
    let from = |params: &Parameters| -> Vec<f64> {
        specs.iter().zip(&ranges).map(|(s, r)| r.unit(rig.value(params, &s.name))).collect()
    };
    let mut searched = plan.search(&search, from(&base), samples, &mut history, &mut progress);
    let mut starts = 1;
    if searched.cost >= cost_nominal && twin != base {
        let again = plan.search(&search, from(&twin), samples, &mut history, &mut progress);
        starts += 1;
        let candidates = searched.candidates + again.candidates;
        if again.cost < searched.cost {
            searched = again;
        }
        searched.candidates = candidates;
    }
    let (u, unsettled) = (searched.u, searched.unsettled);
    // The twin's replay, and the start's where it is another.
    let candidates = searched.candidates + 1 + usize::from(twin != base);
    let fitted = search.set(&u);
    let best = searched.cost;
    // The search is judged against where it started and the twin as it runs, on the same logs:
    // a fit that tracks them worse than either is never returned as an improvement.
    let no_better = (best >= cost_nominal.min(cost_start)).then(|| {
        format!(
            "the search ({starts} start(s)) ended at χ² per step {best:.4}, no better than the twin as it runs ({cost_nominal:.4}) or its start ({cost_start:.4})"
        )
    });
    let seconds_fit = started.elapsed().as_secs_f64();
    let replays = candidates;
    let uncertainty = spreads(rig, logs, &fitted, &specs, samples);
    let (replay_noise, widen) = (uncertainty.replay_noise, uncertainty.widen());
    // A twin that follows the logs to their noise scores about one per compared signal and
    // log; far above that, the fit explains little of the logs, and its spreads (the error's
    // shape around a point that is not the answer) say nothing.
    let matched: f64 = logs.iter().map(|l| l.scale.iter().flatten().filter(|s| **s > 0.0).count() as f64).sum();
    let misfit = (best > MISFIT * matched).then(|| {
        format!(
            "the twin does not follow the logs: χ² per step {best:.1} where one that matched them to their noise would score about {matched:.0} (a replay that diverges, as a free pendulum falling another way, or physics the twin lacks), so no spread holds"
        )
    });
    let parameters = specs
        .iter()
        .zip(&ranges)
        .zip(&u)
        .zip(&uncertainty.spreads)
        .enumerate()
        .map(|(i, (((spec, range), &u), spread))| {
            let value = range.value(u);
            let at_bound = u <= 1e-3 || u >= 1.0 - 1e-3;
            let resolution = resolution(spec, value, rig.dt());
            let not_identifiable = if let Some(why) = &misfit {
                Some(why.clone())
            } else if spread.offset.abs() > resolution {
                Some(format!(
                    "the search had not settled along it: the error still falls towards {:.4e} (its curvature puts the minimum {:+.2e} {} away)",
                    value + spread.offset,
                    spread.offset,
                    spec.unit
                ))
            } else if let Some(last) = Some(searched_spread(range, u, unsettled[i])).filter(|s| *s > resolution) {
                Some(format!("the search had not settled along it: its last generation still spread ±{last:.2e} {}", spec.unit))
            } else if spread.conditional / widen > resolution {
                Some(format!(
                    "the logs' motion barely exercises it: ±{:.3e} {} changes the tracking error by only Δχ² = {:.1} over {samples} samples",
                    spread.probe,
                    spec.unit,
                    (widen * spread.probe / spread.conditional).powi(2),
                ))
            } else if spread.marginal / widen > resolution {
                let partner = spread.partner.map_or("another parameter".to_string(), |(q, r)| format!("{} (correlation {r:+.2})", specs[q].name));
                Some(format!("it trades off against {partner}: the logs' motion does not tell them apart (spread {:.2e})", spread.marginal))
            } else if spread.marginal > resolution {
                Some(format!(
                    "the replay's own numerical noise (±{replay_noise:.0} in χ² over {samples} samples) hides changes of it within ±{:.2e} {}",
                    spread.marginal, spec.unit
                ))
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
        cost_start,
        cost_fitted: best,
        no_better,
        history,
        candidates,
        replays: replays + uncertainty.replays,
        replay_noise,
        seconds: started.elapsed().as_secs_f64(),
        seconds_per_replay: seconds_fit / replays as f64,
        samples,
    })
}

/// How the search runs: which parameters go first, its population and when it has settled.
struct Plan {
    /// The parameters of no joint (the delay), and all of them.
    global: Vec<usize>,
    all: Vec<usize>,
    popsize: usize,
    /// Per parameter, the unit-box spread under which a generation has settled.
    settled: Vec<f64>,
    generations: usize,
}

/// Where one search ended.
struct Searched {
    u: Vec<f64>,
    /// Its total error (χ² per step) there.
    cost: f64,
    /// Replays it took.
    candidates: usize,
    /// The last generation's spread per parameter (unit box): 0 where it was not searched.
    unsettled: Vec<f64>,
}

impl Plan {
    fn of(rig: &Rig, specs: &[ParameterSpec], ranges: &[Range], base: &Parameters, options: &FitOptions) -> Self {
        let (global, joints): (Vec<Block>, Vec<Block>) =
            blocks(rig, specs).into_iter().partition(|b| b.joint.is_none());
        // CMA-ES's own default, 4 + ⌊3 ln n⌋ over the joints' parameters (12 for the UR5e's 18).
        let joint_count = joints.iter().map(|b| b.members.len()).sum::<usize>().max(1);
        let popsize =
            if options.popsize > 0 { options.popsize } else { 4 + (3.0 * (joint_count as f64).ln()).floor() as usize };
        // A search along the delay (or a bias) may stop once its generation spreads less than a
        // half of what the delay must be known to; the joints' parameters once under 2e-3 of the
        // unit box (their spread is checked after, against their resolution).
        let settled = specs
            .iter()
            .zip(ranges)
            .map(|(spec, range)| match spec.kind {
                ParameterKind::CommandDelay | ParameterKind::Bias => {
                    let value = rig.value(base, &spec.name);
                    range.unit_spread(value, resolution(spec, value, rig.dt()) / 2.0)
                }
                _ => 2e-3,
            })
            .collect();
        Self {
            global: global.iter().flat_map(|b| b.members.clone()).collect(),
            all: (0..specs.len()).collect(),
            popsize,
            settled,
            generations: options.generations,
        }
    }

    /// One search from the unit-box point `u`.
    fn search(
        &self,
        search: &Search,
        mut u: Vec<f64>,
        samples: usize,
        history: &mut Vec<Generation>,
        progress: &mut dyn FnMut(&Generation),
    ) -> Searched {
        let (rig, logs, specs, ranges) = (search.rig, search.logs, search.specs, search.ranges);
        let (all, g) = (&self.all, self.generations);
        let mut unsettled = vec![0.0; specs.len()];
        // 1. The delay alone, the rest nominal: it moves every joint, and it is 1-D.
        let basis = Basis::diagonal(&vec![0.1; self.global.len()]);
        let mut candidates =
            search.evolve(&mut u, &self.global, &basis, &self.settled, (g / 2).max(10), 6, history, progress).0;
        // 2. Every parameter in one search scored by the total error: a joint's parameters reach
        //    the other joints' errors too (the arm's dynamics share their efforts), and the delay
        //    every joint's. The error is near a sum of squares of residuals that move smoothly
        //    with the parameters, so its Gauss–Newton curvature (`sensitivity`, n + 1 replays)
        //    shows how they trade off, within and across joints, and where a quadratic model puts
        //    the minimum: the search starts there when that is better (the first step of least
        //    squares, as MuJoCo's sysid takes many), in coordinates whitened by that curvature
        //    (`uncertainty::whitened`), so it need not learn over many generations what the
        //    curvature already says.
        if g > 0 {
            let (mut at, probes) = gauss_newton(rig, logs, &search.set(&u), specs, all);
            candidates += probes;
            if let Some(step) = at.newton_step() {
                // The full step, and half of it where the error is less quadratic than the model.
                let tries: Vec<Vec<f64>> = [1.0, 0.5]
                    .iter()
                    .map(|f| all.iter().map(|&i| ranges[i].unit(ranges[i].value(u[i]) + f * step[i])).collect())
                    .collect();
                let sets: Vec<Parameters> = tries.iter().map(|t| search.set(t)).collect();
                let scores = costs(rig, logs, &sets);
                candidates += sets.len();
                // Against the error where the curvature was measured (its own replay's).
                if let Some(best) =
                    (0..scores.len()).filter(|&k| scores[k] < at.value).min_by(|&a, &b| scores[a].total_cmp(&scores[b]))
                {
                    u = tries[best].clone();
                    // Whitened where the search starts.
                    let (moved, probes) = gauss_newton(rig, logs, &search.set(&u), specs, all);
                    candidates += probes;
                    at = moved;
                }
            }
            let basis = whitened(&at, all, ranges, &u, samples, 10.0, (1e-4, 0.1, 0.1));
            let (n, spread) = search.evolve(&mut u, all, &basis, &self.settled, g, self.popsize, history, progress);
            candidates += n;
            unsettled = spread;
        }
        let cost = costs(rig, logs, std::slice::from_ref(&search.set(&u)))[0];
        Searched { u, cost, candidates: candidates + 1, unsettled }
    }
}
