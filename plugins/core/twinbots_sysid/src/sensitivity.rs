//! How each parameter moves the replay, sample by sample: the Jacobian J of the tracking
//! residuals (`replay::residuals`) by forward differences, one replay per parameter. Its
//! Gauss–Newton curvature 2·JᵀJ covers every pair of parameters at once, across joints too
//! (a joint's damping moves the other joints' errors through the efforts the arm's dynamics
//! share), for n + 1 replays where the cost's own second differences take n(n + 1)/2 + n.

use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::{PreparedLog, residuals};
use crate::rig::{Rig, run};

/// The error's curvature around a point over some parameters: its Hessian (per unit of each
/// parameter) and slope, measured with steps `probe` ([`gauss_newton`]).
#[derive(Clone, Debug)]
pub struct Curvature {
    /// The error (χ² per step, summed over logs) at the point: Σr² of its replay.
    pub value: f64,
    pub hessian: Vec<Vec<f64>>,
    pub slope: Vec<f64>,
    pub probe: Vec<f64>,
}

impl Curvature {
    /// The inverse of the Hessian over the parameters the logs move at all (a parameter they do
    /// not move has no curvature: its row and column are left at 0), `None` if that is singular.
    pub fn inverse(&self) -> Option<Vec<Vec<f64>>> {
        let active: Vec<usize> = (0..self.hessian.len()).filter(|&p| self.hessian[p][p] > 0.0).collect();
        let sub: Vec<Vec<f64>> = active.iter().map(|&p| active.iter().map(|&q| self.hessian[p][q]).collect()).collect();
        let inv = invert(&sub)?;
        let mut out = vec![vec![0.0; self.hessian.len()]; self.hessian.len()];
        for (a, &p) in active.iter().enumerate() {
            for (b, &q) in active.iter().enumerate() {
                out[p][q] = inv[a][b];
            }
        }
        Some(out)
    }

    /// The Newton step −H⁻¹·slope: where the quadratic model of the error has its minimum,
    /// relative to the point measured (per parameter, in its units).
    pub fn newton_step(&self) -> Option<Vec<f64>> {
        let inv = self.inverse()?;
        Some(inv.iter().map(|row| -row.iter().zip(&self.slope).map(|(v, g)| v * g).sum::<f64>()).collect())
    }
}

/// A parameter's finite-difference step, as a share of its value: small enough that the
/// replay is near linear over it, large enough to stand above the solver's rounding (on the UR5e's
/// recovery check, steps of 10 % and of 1 % both left the search at worse fits).
const RELATIVE_STEP: f64 = 0.03;

/// The step of a parameter at 0 (a joint with no armature).
const STEP_AT_ZERO: f64 = 0.01;

/// The total tracking error at `at` and its curvature over the parameters `members` (indices
/// into `specs`): Hessian 2·JᵀJ and slope 2·Jᵀr, per unit of each parameter, in `members`'
/// order. Each parameter is stepped up by [`RELATIVE_STEP`] of its value; a delay by a tenth of
/// a physics step, a bias by 1 mrad (mm). Also returns the replays it took.
pub fn gauss_newton(
    rig: &Rig,
    logs: &[PreparedLog],
    at: &Parameters,
    specs: &[ParameterSpec],
    members: &[usize],
) -> (Curvature, usize) {
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
    let mut value = 0.0;
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
        value += r0.iter().map(|r| r * r).sum::<f64>();
        let columns: Vec<Vec<f64>> =
            (0..d).map(|p| signals[p + 1].iter().zip(r0).map(|(a, b)| (a - b) / steps[p]).collect()).collect();
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
    (Curvature { value, hessian, slope, probe: steps }, sets.len())
}

/// The inverse of a small symmetric matrix by Gauss–Jordan elimination; `None` if singular.
fn invert(m: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let d = m.len();
    let mut a: Vec<Vec<f64>> = m
        .iter()
        .enumerate()
        .map(|(i, row)| row.iter().copied().chain((0..d).map(|j| if i == j { 1.0 } else { 0.0 })).collect())
        .collect();
    for col in 0..d {
        let pivot = (col..d).max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))?;
        if a[pivot][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, pivot);
        let p = a[col][col];
        a[col].iter_mut().for_each(|v| *v /= p);
        for row in 0..d {
            if row != col {
                let f = a[row][col];
                let pivot_row = a[col].clone();
                a[row].iter_mut().zip(pivot_row).for_each(|(v, pv)| *v -= f * pv);
            }
        }
    }
    Some(a.into_iter().map(|row| row[d..].to_vec()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newton_step_reaches_a_quadratics_minimum_and_skips_what_the_logs_do_not_move() {
        // χ²(x) = (x − m)ᵀ A (x − m) around 0: H = 2A, slope = −2Am. The third parameter has no
        // curvature at all.
        let a = [[2.0, 0.5], [0.5, 1.0]];
        let m = [0.3, -0.2];
        let hessian = vec![vec![4.0, 1.0, 0.0], vec![1.0, 2.0, 0.0], vec![0.0, 0.0, 0.0]];
        let slope = vec![-2.0 * (a[0][0] * m[0] + a[0][1] * m[1]), -2.0 * (a[1][0] * m[0] + a[1][1] * m[1]), 0.0];
        let c = Curvature { value: 0.0, hessian, slope, probe: vec![0.01; 3] };
        let step = c.newton_step().expect("the moved parameters' curvature is invertible");
        assert!((step[0] - m[0]).abs() < 1e-12 && (step[1] - m[1]).abs() < 1e-12, "{step:?}");
        assert_eq!(step[2], 0.0);
        let inverse = c.inverse().unwrap();
        assert_eq!(inverse[2], vec![0.0; 3]);
        // H · H⁻¹ = I over the moved ones.
        let product: f64 = (0..2).map(|k| c.hessian[0][k] * inverse[k][1]).sum();
        assert!(product.abs() < 1e-12);
    }
}
