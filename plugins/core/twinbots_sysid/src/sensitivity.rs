//! How each parameter moves the replay, sample by sample: the Jacobian J of the tracking
//! residuals (`replay::residuals`) by forward differences, one replay per parameter. Its
//! Gauss–Newton curvature 2·JᵀJ covers every pair of parameters at once, across joints too
//! (a joint's damping moves the other joints' errors through the efforts the arm's dynamics
//! share), for n + 1 replays where the cost's own second differences take n(n + 1)/2 + n.

use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::{PreparedLog, residuals};
use crate::rig::{Rig, run};
use crate::uncertainty::Curvature;

/// A parameter's finite-difference step, as a share of its value: small enough that the
/// replay is near linear over it, large enough to stand above the solver's rounding (on the UR5e's
/// recovery check, steps of 10 % and of 1 % both left the search at worse fits).
const RELATIVE_STEP: f64 = 0.03;

/// The step of a parameter at 0 (a joint with no armature).
const STEP_AT_ZERO: f64 = 0.01;

/// The curvature of the total tracking error at `at` over the parameters `members` (indices
/// into `specs`): Hessian 2·JᵀJ and slope 2·Jᵀr, per unit of each parameter, in `members`'
/// order. Each parameter is stepped up by [`RELATIVE_STEP`] of its value; a delay by a tenth of
/// a physics step, a bias by 1 mrad (mm). Also returns the replays it took.
pub fn gauss_newton(rig: &Rig, logs: &[PreparedLog], at: &Parameters, specs: &[ParameterSpec], members: &[usize]) -> (Curvature, usize) {
    let d = members.len();
    let steps: Vec<f64> = members
        .iter()
        .map(|&i| {
            let spec = &specs[i];
            let v = at.get(&spec.name).unwrap_or(spec.default);
            match spec.kind {
                ParameterKind::CommandDelay => rig.dt() / 10.0,
                ParameterKind::Bias => 1e-3,
                _ if v.abs() > 0.0 => RELATIVE_STEP * v.abs(),
                _ => STEP_AT_ZERO,
            }
        })
        .collect();
    let mut sets = vec![at.clone()];
    sets.extend(members.iter().zip(&steps).map(|(&i, h)| {
        let mut p = at.clone();
        p.0.insert(specs[i].name.clone(), at.get(&specs[i].name).unwrap_or(specs[i].default) + h);
        p
    }));
    let mut jtj = vec![vec![0.0; d]; d];
    let mut jtr = vec![0.0; d];
    for log in logs {
        // The twin starts where the log does, less the base parameters' encoder bias.
        let start = log.start_positions(rig, at);
        let replays = run(rig, &start, &log.program, &sets);
        let signals: Vec<Vec<f64>> = replays
            .iter()
            .zip(&sets)
            .map(|(twin, params)| {
                let mut r = Vec::new();
                residuals(log, twin, &rig.biases(params), &mut r);
                r
            })
            .collect();
        let r0 = &signals[0];
        let columns: Vec<Vec<f64>> = (0..d).map(|p| signals[p + 1].iter().zip(r0).map(|(a, b)| (a - b) / steps[p]).collect()).collect();
        for p in 0..d {
            jtr[p] += columns[p].iter().zip(r0).map(|(j, r)| j * r).sum::<f64>();
            for q in p..d {
                let v: f64 = columns[p].iter().zip(&columns[q]).map(|(a, b)| a * b).sum();
                jtj[p][q] += v;
                if q != p {
                    jtj[q][p] += v;
                }
            }
        }
    }
    let hessian = jtj.iter().map(|row| row.iter().map(|v| 2.0 * v).collect()).collect();
    let slope = jtr.iter().map(|v| 2.0 * v).collect();
    (Curvature { hessian, slope, probe: steps }, sets.len())
}
