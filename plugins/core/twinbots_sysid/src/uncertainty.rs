//! How well the logs pin each fitted parameter down: the curvature of the tracking error (χ²,
//! errors in units of the logs' noise) around the fit, per block, by finite differences; its
//! inverse is the fit's covariance (Gauss–Newton: C = 2 H⁻¹ for H the Hessian of the total χ²).
//! A parameter that trades off against another (damping against friction when speeds vary
//! little) has a small conditional spread but a large marginal one: the marginal is reported.

use twinbots_sim::{ParameterKind, ParameterSpec, Parameters};

use crate::replay::PreparedLog;
use crate::rig::Rig;
use crate::search::{Basis, Block, Range, joint_costs};

/// One parameter's uncertainty.
#[derive(Clone, Debug)]
pub struct Spread {
    /// The probe step the curvature was measured with.
    pub probe: f64,
    /// Standard deviation with the other parameters also free (marginal).
    pub marginal: f64,
    /// Standard deviation with the other parameters held at the fit.
    pub conditional: f64,
    /// The parameter of the same block it correlates with most, and the correlation.
    pub partner: Option<(usize, f64)>,
    /// How far along this parameter alone the error's minimum lies from the fit (the slope over
    /// the curvature): near 0 when the search converged along it.
    pub offset: f64,
}

/// The error's curvature around a point, for one block: its Hessian (per unit of each
/// parameter) and slope, measured with steps `probe`.
#[derive(Clone, Debug)]
pub struct Curvature {
    pub hessian: Vec<Vec<f64>>,
    pub slope: Vec<f64>,
    pub probe: Vec<f64>,
}

/// Measures each block's curvature at `at` by finite differences of the total error, each block
/// probed in arenas of its own (one joint's parameters reach the others' errors too: the
/// drives' efforts are solved together). Also returns the replays it took.
pub fn curvatures(rig: &Rig, logs: &[PreparedLog], at: &Parameters, specs: &[ParameterSpec], blocks: &[Block]) -> (Vec<Curvature>, usize) {
    let probes: Vec<f64> = specs
        .iter()
        .map(|spec| {
            let v = at.get(&spec.name).unwrap_or(spec.default);
            match spec.kind {
                ParameterKind::CommandDelay => rig.dt(),
                ParameterKind::Bias => 0.01,
                _ if v.abs() > 0.0 => 0.3 * v.abs(),
                _ => 0.01,
            }
        })
        .collect();
    // A parameter that cannot go a probe below its value (a damping at 0) is probed forward:
    // +1 and +2 probes instead of ±1.
    let forward: Vec<bool> = specs
        .iter()
        .zip(&probes)
        .map(|(spec, h)| spec.kind != ParameterKind::Bias && at.get(&spec.name).unwrap_or(spec.default) - h < 0.0)
        .collect();
    // Per block, the probe patterns in member coordinates: ±each (or +1, +2), then +each pair.
    let patterns = |block: &Block| -> Vec<Vec<(usize, f64)>> {
        let d = block.members.len();
        let second = |p: usize| if forward[block.members[p]] { 2.0 } else { -1.0 };
        let mut out: Vec<Vec<(usize, f64)>> = (0..d).flat_map(|p| [vec![(p, 1.0)], vec![(p, second(p))]]).collect();
        out.extend((0..d).flat_map(|p| (p + 1..d).map(move |q| vec![(p, 1.0), (q, 1.0)])));
        out
    };
    let mut sets = vec![at.clone()];
    for block in blocks {
        sets.extend(patterns(block).iter().map(|p| probe_set(p, &[block], at, specs, &probes)));
    }
    let costs: Vec<f64> = joint_costs(rig, logs, &sets).iter().map(|c| c.iter().sum()).collect();
    let j0 = costs[0];
    let mut offset = 1;
    let out = blocks
        .iter()
        .map(|block| {
            let d = block.members.len();
            let h: Vec<f64> = block.members.iter().map(|&i| probes[i]).collect();
            let score = |k: usize| costs[offset + k];
            let (plus, other) = (|p: usize| score(2 * p), |p: usize| score(2 * p + 1));
            let mut hessian = vec![vec![0.0; d]; d];
            let mut pair = 2 * d;
            for p in 0..d {
                hessian[p][p] = if forward[block.members[p]] {
                    (other(p) - 2.0 * plus(p) + j0) / (h[p] * h[p])
                } else {
                    (plus(p) + other(p) - 2.0 * j0) / (h[p] * h[p])
                };
                for q in p + 1..d {
                    let v = (score(pair) - plus(p) - plus(q) + j0) / (h[p] * h[q]);
                    hessian[p][q] = v;
                    hessian[q][p] = v;
                    pair += 1;
                }
            }
            let slope = (0..d)
                .map(|p| if forward[block.members[p]] { (4.0 * plus(p) - 3.0 * j0 - other(p)) / (2.0 * h[p]) } else { (plus(p) - other(p)) / (2.0 * h[p]) })
                .collect();
            offset += patterns(block).len();
            Curvature { hessian, slope, probe: h }
        })
        .collect();
    (out, sets.len())
}

/// Measures every parameter's spread at `fitted` from its block's curvature. `samples` is the
/// count the χ² sums over. Parameters in none of `blocks` get `None`. Also returns the replays
/// it took.
pub fn spreads(rig: &Rig, logs: &[PreparedLog], fitted: &Parameters, specs: &[ParameterSpec], blocks: &[Block], samples: usize) -> (Vec<Option<Spread>>, usize) {
    let (curvatures, replays) = curvatures(rig, logs, fitted, specs, blocks);
    let mut out: Vec<Option<Spread>> = vec![None; specs.len()];
    let n = samples as f64;
    for (block, c) in blocks.iter().zip(&curvatures) {
        let hessian = &c.hessian;
        let d = block.members.len();
        let conditional: Vec<f64> = (0..d).map(|p| (2.0 / (n * hessian[p][p].max(1e-300))).sqrt()).collect();
        let covariance = invert(hessian).map(|inv| inv.iter().map(|row| row.iter().map(|v| 2.0 * v / n).collect::<Vec<f64>>()).collect::<Vec<_>>());
        for p in 0..d {
            let (marginal, partner) = match &covariance {
                Some(c) if c[p][p] > 0.0 => {
                    let partner = (0..d)
                        .filter(|&q| q != p && c[q][q] > 0.0)
                        .map(|q| (block.members[q], c[p][q] / (c[p][p] * c[q][q]).sqrt()))
                        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
                    (c[p][p].sqrt().max(conditional[p]), partner)
                }
                // Not convex here (the fit is off the minimum, or the error is flat): the
                // conditional spread is all there is.
                _ => (f64::INFINITY, None),
            };
            let offset = if hessian[p][p] > 0.0 { -c.slope[p] / hessian[p][p] } else { f64::INFINITY };
            out[block.members[p]] = Some(Spread { probe: c.probe[p], marginal, conditional: conditional[p], partner, offset });
        }
    }
    (out, replays)
}

/// The fit with a probe pattern applied to `blocks`' parameters.
fn probe_set(pattern: &[(usize, f64)], blocks: &[&Block], fitted: &Parameters, specs: &[ParameterSpec], probes: &[f64]) -> Parameters {
    let mut params = fitted.clone();
    for block in blocks {
        for &(m, sign) in pattern {
            if let Some(&i) = block.members.get(m) {
                let spec = &specs[i];
                let v = fitted.get(&spec.name).unwrap_or(spec.default) + sign * probes[i];
                params.0.insert(spec.name.clone(), if spec.kind == ParameterKind::Bias { v } else { v.max(0.0) });
            }
        }
    }
    params
}

/// The inverse of a small symmetric matrix by Gauss–Jordan elimination; `None` if singular.
fn invert(m: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let d = m.len();
    let mut a: Vec<Vec<f64>> = m.iter().enumerate().map(|(i, row)| row.iter().copied().chain((0..d).map(|j| if i == j { 1.0 } else { 0.0 })).collect()).collect();
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

/// A search basis over `members` (indices into `specs`) at unit-box point `u`: per block, `k`
/// times the fit's statistical spread there, correlations included (the Cholesky factor of
/// k²·2/n·H⁻¹, H the block's curvature per unit-box unit), so that the search starts as round
/// in its coordinates as the error is. A block whose curvature is not positive definite falls
/// back to one step per parameter (k conditional spreads, or `fallback`). Each parameter's step
/// is kept within [`min`, `max`] of the unit box.
#[allow(clippy::too_many_arguments)]
pub fn whitened(curvatures: &[Curvature], blocks: &[Block], members: &[usize], ranges: &[Range], u: &[f64], samples: usize, k: f64, limits: (f64, f64, f64)) -> Basis {
    let (min, max, fallback) = limits;
    let n = samples as f64;
    // Per block: its curvature per unit-box unit (H scaled by the parameter units per unit-box
    // unit at the point), the slope likewise, and the curvature's inverse if it has one.
    let scaled: Vec<(Vec<Vec<f64>>, Vec<f64>, Option<Vec<Vec<f64>>>)> = blocks
        .iter()
        .zip(curvatures)
        .map(|(block, c)| {
            let per_unit: Vec<f64> = block.members.iter().map(|&i| 1.0 / ranges[i].unit_spread(ranges[i].value(u[i]), 1.0)).collect();
            let d = block.members.len();
            let h: Vec<Vec<f64>> = (0..d).map(|p| (0..d).map(|q| c.hessian[p][q] * per_unit[p] * per_unit[q]).collect()).collect();
            let slope = (0..d).map(|p| c.slope[p] * per_unit[p]).collect();
            let inverse = invert(&h);
            (h, slope, inverse)
        })
        .collect();
    // How far the minimum lies, in statistical spreads: the Newton step −H⁻¹·slope of each
    // block, measured in H (slopeᵀH⁻¹slope). The search's first steps reach that far.
    let distance2: f64 = scaled
        .iter()
        .filter_map(|(_, slope, inverse)| {
            let inv = inverse.as_ref()?;
            let quad: f64 = slope.iter().enumerate().map(|(p, gp)| gp * inv[p].iter().zip(slope).map(|(v, gq)| v * gq).sum::<f64>()).sum();
            (quad.is_finite() && quad > 0.0).then_some(n / 2.0 * quad)
        })
        .sum();
    let k = k.max(distance2.sqrt() / (members.len().max(1) as f64).sqrt());
    let position = |i: usize| members.iter().position(|&m| m == i);
    let mut basis = vec![vec![0.0; members.len()]; members.len()];
    for (block, (h, _, inverse)) in blocks.iter().zip(&scaled) {
        let d = block.members.len();
        let factor = inverse
            .as_ref()
            .map(|inv| inv.iter().map(|row| row.iter().map(|v| k * k * 2.0 / n * v).collect::<Vec<f64>>()).collect::<Vec<_>>())
            .and_then(|cov| cholesky(&cov));
        let factor = factor.unwrap_or_else(|| {
            let step = |p: usize| if h[p][p] > 0.0 { k * (2.0 / (n * h[p][p])).sqrt() } else { fallback };
            (0..d).map(|p| (0..d).map(|q| if p == q { step(p) } else { 0.0 }).collect()).collect()
        });
        for p in 0..d {
            let Some(row) = position(block.members[p]) else { continue };
            // A row's norm is its parameter's step: scaled into the limits, directions kept.
            let norm = factor[p].iter().map(|v| v * v).sum::<f64>().sqrt();
            let scale = if norm > 0.0 { norm.clamp(min, max) / norm } else { 0.0 };
            for q in 0..d {
                if let Some(col) = position(block.members[q]) {
                    basis[row][col] = factor[p][q] * scale;
                }
            }
            if norm == 0.0 {
                basis[row][row] = fallback;
            }
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
