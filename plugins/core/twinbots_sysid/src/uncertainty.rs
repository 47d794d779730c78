//! How well the logs pin each fitted parameter down: the curvature of the tracking error (χ²,
//! errors in units of the logs' noise) around the fit over all fitted parameters, from the
//! residuals' sensitivities (`sensitivity`); its inverse is the fit's covariance
//! (Gauss–Newton: C = 2 H⁻¹ for H the Hessian of the total χ²). A parameter that trades off
//! against another (damping against friction when speeds vary little, or a joint's damping
//! against the next joint's) has a small conditional spread but a large marginal one: the
//! marginal is reported.

use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::PreparedLog;
use crate::rig::Rig;
use crate::search::{Basis, Range, costs};
use crate::sensitivity::{Curvature, gauss_newton};

/// One parameter's uncertainty.
#[derive(Clone, Debug)]
pub struct Spread {
    /// The probe step the curvature was measured with.
    pub probe: f64,
    /// Standard deviation with the other parameters also free (marginal).
    pub marginal: f64,
    /// Standard deviation with the other parameters held at the fit.
    pub conditional: f64,
    /// The fitted parameter it correlates with most (index into the specs), and the correlation.
    pub partner: Option<(usize, f64)>,
    /// How far the error's minimum lies from the fit along this parameter, by the quadratic
    /// model of the error (its part of the Newton step): near 0 when the search converged.
    pub offset: f64,
}

/// How well the logs pin the fit down.
#[derive(Clone, Debug)]
pub struct Uncertainty {
    /// Per fitted parameter.
    pub spreads: Vec<Spread>,
    /// The replay's own numerical noise, in total χ² (over all samples): how far the error at
    /// points the statistics cannot tell apart from the fit scatters about its quadratic model.
    /// A long replay's error is not smooth in the parameters on that scale (measured, not
    /// explained: see docs/logs.md); the spreads are widened to where a change stands above it.
    pub replay_noise: f64,
    pub replays: usize,
}

impl Uncertainty {
    /// How much wider than the statistics' the spreads are for the replay's noise: a change of
    /// the error under the noise is not seen, so a spread is where the error has risen by one
    /// (statistics) or by the noise, whichever is more.
    pub fn widen(&self) -> f64 {
        widening(self.replay_noise)
    }
}

fn widening(replay_noise: f64) -> f64 {
    replay_noise.max(1.0).sqrt()
}

/// Points the replay-noise probe measures, per distance from the fit.
const NOISE_PROBES: usize = 8;

/// How many times at most the noise is measured again further out.
const NOISE_ROUNDS: usize = 3;

/// Measures every one of `specs`' spreads at `fitted` from the error's Gauss–Newton curvature
/// over all of them (correlations across joints included), widened by the replay's numerical
/// noise. `samples` is the count the χ² sums over.
pub fn spreads(
    rig: &Rig,
    logs: &[PreparedLog],
    fitted: &Parameters,
    specs: &[ParameterSpec],
    samples: usize,
) -> Uncertainty {
    let all: Vec<usize> = (0..specs.len()).collect();
    let (c, mut replays) = gauss_newton(rig, logs, fitted, specs, &all);
    let n = samples as f64;
    let d = specs.len();
    let covariance = c
        .inverse()
        .map(|inv| inv.iter().map(|row| row.iter().map(|v| 2.0 * v / n).collect::<Vec<f64>>()).collect::<Vec<_>>());
    // The noise may grow with how far apart the replays' parameters are (a pendulum that falls
    // over amplifies any change), so it is measured again as far out as the spreads it widens,
    // until it stops growing there.
    let replay_noise = match covariance.as_ref().and_then(|cov| cholesky(cov)) {
        Some(factor) => {
            let (mut noise, probes) = replay_noise(rig, logs, fitted, specs, &c, &factor, n, 1.0);
            replays += probes;
            for _ in 0..NOISE_ROUNDS {
                let (far, probes) = replay_noise(rig, logs, fitted, specs, &c, &factor, n, widening(noise));
                replays += probes;
                let grew = far > 2.0 * noise;
                noise = noise.max(far);
                if !grew {
                    break;
                }
            }
            noise
        }
        None => 0.0,
    };
    let widen = widening(replay_noise);
    let conditional: Vec<f64> = (0..d).map(|p| widen * (2.0 / (n * c.hessian[p][p].max(1e-300))).sqrt()).collect();
    let newton = c.newton_step();
    let spreads = (0..d)
        .map(|p| {
            let (marginal, partner) = match &covariance {
                Some(cov) if cov[p][p] > 0.0 => {
                    let partner = (0..d)
                        .filter(|&q| q != p && cov[q][q] > 0.0)
                        .map(|q| (q, cov[p][q] / (cov[p][p] * cov[q][q]).sqrt()))
                        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
                    ((widen * cov[p][p].sqrt()).max(conditional[p]), partner)
                }
                // The logs do not move it, or its curvature is singular with others': the
                // conditional spread is all there is.
                _ => (f64::INFINITY, None),
            };
            let offset = newton.as_ref().map_or(f64::INFINITY, |step| step[p]);
            Spread { probe: c.probe[p], marginal, conditional: conditional[p], partner, offset }
        })
        .collect();
    Uncertainty { spreads, replay_noise, replays }
}

/// The replay's numerical noise at `fitted` (total χ²): the RMS, over [`NOISE_PROBES`] points
/// `scale` statistical spreads away (`factor`: the covariance's Cholesky factor, drawn with a
/// fixed seed), of the error's departure from its quadratic model `c`. Also returns the replays.
#[allow(clippy::too_many_arguments)]
fn replay_noise(
    rig: &Rig,
    logs: &[PreparedLog],
    fitted: &Parameters,
    specs: &[ParameterSpec],
    c: &Curvature,
    factor: &[Vec<f64>],
    n: f64,
    scale: f64,
) -> (f64, usize) {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x05ee_d0f0_015e);
    let d = specs.len();
    let steps: Vec<Vec<f64>> = (0..NOISE_PROBES)
        .map(|_| {
            let z: Vec<f64> = (0..d).map(|_| StandardNormal.sample(&mut rng)).collect();
            // A unit draw in every direction at once is √d spreads out: scaled to one.
            (0..d)
                .map(|p| factor[p].iter().zip(&z).map(|(l, z)| l * z).sum::<f64>() / (d as f64).sqrt() * scale)
                .collect()
        })
        .collect();
    let value = |i: usize| fitted.get(&specs[i].name).unwrap_or(specs[i].default);
    let sets: Vec<Parameters> = steps
        .iter()
        .map(|step| {
            let mut p = fitted.clone();
            for (i, s) in step.iter().enumerate() {
                let v = value(i) + s;
                p.0.insert(specs[i].name.clone(), if specs[i].kind == ParameterKind::Bias { v } else { v.max(0.0) });
            }
            p
        })
        .collect();
    let costs = costs(rig, logs, &sets);
    let model = |step: &[f64]| -> f64 {
        let linear: f64 = c.slope.iter().zip(step).map(|(g, s)| g * s).sum();
        let quadratic: f64 = (0..d).map(|p| step[p] * (0..d).map(|q| c.hessian[p][q] * step[q]).sum::<f64>()).sum();
        linear + quadratic / 2.0
    };
    // The error at the fit is the curvature's own (its replay's).
    let sq: f64 = steps.iter().zip(&costs).map(|(step, y)| (n * (y - c.value - model(step))).powi(2)).sum();
    ((sq / NOISE_PROBES as f64).sqrt(), sets.len())
}

/// A search basis over the parameters `members` (indices into `ranges` and `u`) at unit-box
/// point `u`, from the error's `curvature` over them: `k` times the fit's statistical spread
/// there, correlations included (the Cholesky factor of k²·2/n·H⁻¹, H per unit-box unit), so
/// that the search starts as round in its coordinates as the error is. If the curvature is not
/// positive definite, one step per parameter (k conditional spreads, or `fallback`). Each
/// parameter's step is kept within [`min`, `max`] of the unit box.
#[allow(clippy::too_many_arguments)]
pub fn whitened(
    curvature: &Curvature,
    members: &[usize],
    ranges: &[Range],
    u: &[f64],
    samples: usize,
    k: f64,
    limits: (f64, f64, f64),
) -> Basis {
    let (min, max, fallback) = limits;
    let n = samples as f64;
    let d = members.len();
    // The curvature per unit-box unit (H scaled by the parameter units per unit-box unit at the
    // point), the slope likewise.
    let per_unit: Vec<f64> = members.iter().map(|&i| 1.0 / ranges[i].unit_spread(ranges[i].value(u[i]), 1.0)).collect();
    let scaled = Curvature {
        value: curvature.value,
        hessian: (0..d)
            .map(|p| (0..d).map(|q| curvature.hessian[p][q] * per_unit[p] * per_unit[q]).collect())
            .collect(),
        slope: (0..d).map(|p| curvature.slope[p] * per_unit[p]).collect(),
        probe: curvature.probe.clone(),
    };
    let h = &scaled.hessian;
    let inverse = scaled.inverse();
    // How far the minimum lies, in statistical spreads: the Newton step −H⁻¹·slope measured in
    // H (slopeᵀH⁻¹slope). The search's first steps reach that far.
    let distance2 = inverse.as_ref().map_or(0.0, |inv| {
        let quad: f64 = scaled
            .slope
            .iter()
            .enumerate()
            .map(|(p, gp)| gp * inv[p].iter().zip(&scaled.slope).map(|(v, gq)| v * gq).sum::<f64>())
            .sum();
        if quad.is_finite() && quad > 0.0 { n / 2.0 * quad } else { 0.0 }
    });
    let k = k.max(distance2.sqrt() / (d.max(1) as f64).sqrt());
    let factor = inverse
        .map(|inv| {
            inv.iter().map(|row| row.iter().map(|v| k * k * 2.0 / n * v).collect::<Vec<f64>>()).collect::<Vec<_>>()
        })
        .and_then(|cov| cholesky(&cov));
    let factor = factor.unwrap_or_else(|| {
        let step = |p: usize| if h[p][p] > 0.0 { k * (2.0 / (n * h[p][p])).sqrt() } else { fallback };
        (0..d).map(|p| (0..d).map(|q| if p == q { step(p) } else { 0.0 }).collect()).collect()
    });
    let mut basis = vec![vec![0.0; d]; d];
    for p in 0..d {
        // A row's norm is its parameter's step: scaled into the limits, directions kept.
        let norm = factor[p].iter().map(|v| v * v).sum::<f64>().sqrt();
        let scale = if norm > 0.0 { norm.clamp(min, max) / norm } else { 0.0 };
        for q in 0..d {
            basis[p][q] = factor[p][q] * scale;
        }
        if norm == 0.0 {
            basis[p][p] = fallback;
        }
    }
    Basis(basis)
}

/// The lower-triangular L with L·Lᵀ = m; `None` unless m is positive definite.
fn cholesky(m: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let d = m.len();
    let mut l = vec![vec![0.0; d]; d];
    for i in 0..d {
        for j in 0..=i {
            let sum: f64 = (0..j).map(|k| l[i][k] * l[j][k]).sum();
            if i == j {
                let v = m[i][i] - sum;
                if !(v > 0.0 && v.is_finite()) {
                    return None;
                }
                l[i][j] = v.sqrt();
            } else {
                l[i][j] = (m[i][j] - sum) / l[j][j];
            }
        }
    }
    Some(l)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_whitened_basis_is_round_where_the_error_is() {
        // Two parameters that trade off (correlated curvature): the basis' rows, mapped through
        // the curvature, are orthogonal with equal lengths (before the step limits apply).
        let range = Range { lo: 0.0, hi: 1.0, log: false };
        let c = Curvature {
            value: 0.0,
            hessian: vec![vec![2.0, 1.8], vec![1.8, 2.0]],
            slope: vec![0.0, 0.0],
            probe: vec![0.01; 2],
        };
        let Basis(b) = whitened(&c, &[0, 1], &[range, range], &[0.5, 0.5], 1_000_000, 1.0, (0.0, 1.0, 0.1));
        // Columns of B are the search's axes: Bᵀ H B ∝ I.
        let m = |i: usize, j: usize| -> f64 {
            (0..2).map(|p| (0..2).map(|q| b[p][i] * c.hessian[p][q] * b[q][j]).sum::<f64>()).sum()
        };
        assert!(m(0, 1).abs() < 1e-9 * m(0, 0), "{b:?}");
        assert!((m(0, 0) / m(1, 1) - 1.0).abs() < 1e-9, "{b:?}");
    }
}
