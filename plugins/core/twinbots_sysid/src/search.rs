//! The search behind `identify`: CMA-ES (fcmaes-core, ask/tell) over parameters in a unit box
//! each, one candidate per arena, every candidate scored by its total tracking error. Blocks
//! group parameters by joint; `identify` decides which search together, and in what order.

use fcmaes_core::cmaes::{Cmaes, CmaesParams};
use fcmaes_core::fitness::Fitness;
use serde::Serialize;
use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::{PreparedLog, tracking_cost};
use crate::rig::{Rig, run};

/// A generation's costs.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Generation {
    pub generation: usize,
    pub best: f64,
    pub mean: f64,
    pub best_so_far: f64,
}

/// Where a parameter may go, and how the optimiser's unit box maps onto it.
#[derive(Clone, Copy, Debug)]
pub struct Range {
    pub lo: f64,
    pub hi: f64,
    /// Log-spaced (positive scales) or linear.
    pub log: bool,
}

impl Range {
    pub fn of(spec: &ParameterSpec, dt: f64) -> Self {
        match spec.kind {
            ParameterKind::CommandDelay => {
                Self { lo: 0.0, hi: (spec.default * 3.0).max(8.0 * dt).max(0.05), log: false }
            }
            ParameterKind::Bias => Self { lo: spec.default - 0.05, hi: spec.default + 0.05, log: false },
            _ if spec.default > 0.0 => Self { lo: spec.default / 4.0, hi: spec.default * 4.0, log: true },
            ParameterKind::Armature => Self { lo: 0.0, hi: 0.5, log: false },
            _ => Self { lo: 0.0, hi: 10.0, log: false },
        }
    }

    pub fn value(&self, u: f64) -> f64 {
        let u = u.clamp(0.0, 1.0);
        if self.log { self.lo * (self.hi / self.lo).powf(u) } else { self.lo + (self.hi - self.lo) * u }
    }

    /// A spread in the parameter's units as one in the unit box, at `value`.
    pub fn unit_spread(&self, value: f64, spread: f64) -> f64 {
        if self.log { spread / (value.max(self.lo) * (self.hi / self.lo).ln()) } else { spread / (self.hi - self.lo) }
    }

    pub fn unit(&self, value: f64) -> f64 {
        let value = value.clamp(self.lo, self.hi);
        if self.log {
            (value / self.lo).ln() / (self.hi / self.lo).ln()
        } else {
            (value - self.lo) / (self.hi - self.lo)
        }
    }
}

/// Parameters searched together: those of one joint (index into the rig's joints), or those
/// of none.
#[derive(Clone, Debug)]
pub struct Block {
    pub members: Vec<usize>,
    pub joint: Option<usize>,
}

/// The blocks of `specs`: one per joint that has fitted parameters, one for the rest.
pub fn blocks(rig: &Rig, specs: &[ParameterSpec]) -> Vec<Block> {
    let mut out: Vec<Block> = Vec::new();
    for (i, spec) in specs.iter().enumerate() {
        let joint = spec.joint.as_ref().and_then(|j| rig.joints.iter().position(|n| n == j));
        match out.iter_mut().find(|b| b.joint == joint) {
            Some(block) => block.members.push(i),
            None => out.push(Block { members: vec![i], joint }),
        }
    }
    out
}

/// The tracking error of each parameter set over the logs, per joint (one arena per set).
pub fn joint_costs(rig: &Rig, logs: &[PreparedLog], sets: &[Parameters]) -> Vec<Vec<f64>> {
    let mut total = vec![vec![0.0; rig.joints.len()]; sets.len()];
    for log in logs {
        // The twin starts where the log does, less the base parameters' encoder bias.
        let start = log.start_positions(rig, &sets[0]);
        for ((cost, twin), params) in total.iter_mut().zip(run(rig, &start, &log.program, sets)).zip(sets) {
            for (c, t) in cost.iter_mut().zip(tracking_cost(log, &twin, &rig.biases(params))) {
                *c += t;
            }
        }
    }
    total
}

/// The summed tracking error of each parameter set over the logs.
pub fn costs(rig: &Rig, logs: &[PreparedLog], sets: &[Parameters]) -> Vec<f64> {
    joint_costs(rig, logs, sets).iter().map(|c| c.iter().sum()).collect()
}

/// The coordinates a search moves in: the members' unit-box point is `start + B·z`, and the
/// search's first step in `z` is 1 along every axis. A diagonal `B` is one step size per
/// parameter; a whitened one (`uncertainty::whitened`) also undoes how the parameters trade
/// off against each other, so the search need not learn it first.
#[derive(Clone, Debug)]
pub struct Basis(pub Vec<Vec<f64>>);

impl Basis {
    /// One step size per member.
    pub fn diagonal(steps: &[f64]) -> Self {
        Self(
            (0..steps.len()).map(|i| (0..steps.len()).map(|j| if i == j { steps[i] } else { 0.0 }).collect()).collect(),
        )
    }

    fn point(&self, start: &[f64], z: &[f64]) -> Vec<f64> {
        start.iter().zip(&self.0).map(|(s, row)| s + row.iter().zip(z).map(|(b, z)| b * z).sum::<f64>()).collect()
    }
}

/// A search over `specs` (with `ranges`), the other parameters at `base`.
pub struct Search<'a> {
    pub rig: &'a Rig,
    pub logs: &'a [PreparedLog],
    pub specs: &'a [ParameterSpec],
    pub ranges: &'a [Range],
    pub base: &'a Parameters,
    pub seed: u64,
}

impl Search<'_> {
    /// The parameter set at unit-box point `u`.
    pub fn set(&self, u: &[f64]) -> Parameters {
        let mut p = self.base.clone();
        for ((spec, range), &u) in self.specs.iter().zip(self.ranges).zip(u) {
            p.0.insert(spec.name.clone(), range.value(u));
        }
        p
    }

    /// Searches the parameters `members` together from `u`, in the coordinates of `basis` (over
    /// the members, in the unit box), for up to `generations` of `popsize`, every candidate
    /// scored by its total error, stopping early once every one's generation spreads less than
    /// its `settled`; writes the best point into `u`. Returns the candidates evaluated and, per
    /// parameter searched, the spread of the last generation in the unit box (how far from
    /// settled the search was when it stopped).
    #[allow(clippy::too_many_arguments)]
    pub fn evolve(
        &self,
        u: &mut [f64],
        members: &[usize],
        basis: &Basis,
        settled: &[f64],
        generations: usize,
        popsize: usize,
        history: &mut Vec<Generation>,
        progress: &mut dyn FnMut(&Generation),
    ) -> (usize, Vec<f64>) {
        let mut last_spread = vec![0.0; u.len()];
        if members.is_empty() || generations == 0 {
            return (0, last_spread);
        }
        let dim = members.len();
        let origin: Vec<f64> = members.iter().map(|&m| u[m]).collect();
        let params = CmaesParams {
            popsize: popsize as i32,
            seed: self.seed.wrapping_add(history.len() as u64 * 97),
            ..CmaesParams::default()
        };
        // The unit box is far inside these bounds whatever the basis: points beyond it clamp.
        let bound = 1e4;
        let mut cma = Cmaes::new(
            Fitness::bounded(dim, 1, &vec![-bound; dim], &vec![bound; dim]),
            &vec![0.0; dim],
            &vec![1.0; dim],
            &params,
        );
        let start: f64 = costs(self.rig, self.logs, &[self.set(u)])[0];
        let mut best = (start, origin.clone());
        let mut candidates = 1;
        for _ in 0..generations {
            let zs = cma.ask();
            let population: Vec<Vec<f64>> =
                zs.iter().map(|z| basis.point(&origin, z).into_iter().map(|v| v.clamp(0.0, 1.0)).collect()).collect();
            let sets: Vec<Parameters> = population
                .iter()
                .map(|x| {
                    let mut point = u.to_vec();
                    for (&index, v) in members.iter().zip(x) {
                        point[index] = *v;
                    }
                    self.set(&point)
                })
                .collect();
            let ys = costs(self.rig, self.logs, &sets);
            candidates += ys.len();
            for (y, x) in ys.iter().zip(&population) {
                if *y < best.0 {
                    best = (*y, x.clone());
                }
            }
            cma.tell(&ys);
            let spread = spread(&population);
            for (&index, s) in members.iter().zip(&spread) {
                last_spread[index] = *s;
            }
            let g = Generation {
                generation: history.len(),
                best: ys.iter().copied().fold(f64::INFINITY, f64::min),
                mean: ys.iter().sum::<f64>() / ys.len() as f64,
                best_so_far: best.0,
            };
            progress(&g);
            history.push(g);
            if members.iter().zip(&spread).all(|(&index, s)| *s < settled[index]) {
                break;
            }
        }
        for (&index, v) in members.iter().zip(best.1) {
            u[index] = v;
        }
        (candidates, last_spread)
    }
}

/// Per coordinate, the standard deviation of a generation.
fn spread(population: &[Vec<f64>]) -> Vec<f64> {
    let n = population.len() as f64;
    (0..population[0].len())
        .map(|i| {
            let mean = population.iter().map(|p| p[i]).sum::<f64>() / n;
            (population.iter().map(|p| (p[i] - mean).powi(2)).sum::<f64>() / n).sqrt()
        })
        .collect()
}
