//! Figures over seeds: a learning result of one seed cannot be told from noise, so headline
//! figures are the median and interquartile range over several runs (and, where it fits,
//! rliable's interquartile mean), and learning curves are drawn as the median with the band
//! between the quartiles.

/// The `q`-quantile (0 ≤ q ≤ 1) of `values`, interpolated linearly between order statistics
/// (NumPy's default); `None` for no values. Infinite values sort last (unsolved runs).
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
    if sorted.is_empty() {
        return None;
    }
    sorted.sort_by(f64::total_cmp);
    let position = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (low, high) = (position.floor() as usize, position.ceil() as usize);
    let (a, b) = (sorted[low], sorted[high]);
    Some(if low == high || a == b { a } else { a + (b - a) * (position - low as f64) })
}

/// Median and quartiles of a figure over seeds.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Spread {
    pub median: f64,
    pub q1: f64,
    pub q3: f64,
    /// rliable's interquartile mean: the mean of the middle half (with fractional weights at its
    /// edges), robust to an outlying seed and less noisy than the median.
    pub iqm: f64,
    pub runs: usize,
}

impl Spread {
    /// `None` for no values. Infinite values (a run that never solved) take part in the
    /// quantiles as larger than any other, so a median is infinite when half the runs failed.
    pub fn of(values: &[f64]) -> Option<Self> {
        Some(Self {
            median: quantile(values, 0.5)?,
            q1: quantile(values, 0.25)?,
            q3: quantile(values, 0.75)?,
            iqm: interquartile_mean(values)?,
            runs: values.len(),
        })
    }
}

/// The mean of the middle 50 % of `values`: each sorted value weighted by how much of its
/// 1/n share of the distribution lies between the 25th and 75th percentiles.
pub fn interquartile_mean(values: &[f64]) -> Option<f64> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
    if sorted.is_empty() {
        return None;
    }
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len() as f64;
    let (mut sum, mut weight) = (0.0, 0.0);
    for (i, v) in sorted.iter().enumerate() {
        let (from, to) = (i as f64 / n, (i + 1) as f64 / n);
        let w = (to.min(0.75) - from.max(0.25)).max(0.0);
        if w > 0.0 {
            sum += w * v;
            weight += w;
        }
    }
    Some(sum / weight)
}

/// The value of a curve (points sorted by x) at `x`: linear between its points, its last value
/// after its end (a run that stopped, solved, stays where it stopped), `None` before its start.
pub fn value_at(curve: &[(f64, f64)], x: f64) -> Option<f64> {
    let first = curve.first()?;
    if x < first.0 {
        return None;
    }
    let i = curve.partition_point(|p| p.0 <= x);
    if i == curve.len() {
        return Some(curve[i - 1].1);
    }
    let (a, b) = (curve[i - 1], curve[i]);
    Some(a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0))
}

/// Median and quartiles of several curves at `points` evenly spaced x from 0 to the furthest
/// curve's end: `(x, q1, median, q3)` wherever at least one curve has begun.
pub fn band(curves: &[Vec<(f64, f64)>], points: usize) -> Vec<(f64, f64, f64, f64)> {
    let end = curves.iter().filter_map(|c| c.last()).map(|p| p.0).fold(0.0, f64::max);
    (0..points.max(2))
        .filter_map(|i| {
            let x = end * i as f64 / (points.max(2) - 1) as f64;
            let ys: Vec<f64> = curves.iter().filter_map(|c| value_at(c, x)).collect();
            Some((x, quantile(&ys, 0.25)?, quantile(&ys, 0.5)?, quantile(&ys, 0.75)?))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_as_numpy_does() {
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(quantile(&v, 0.5), Some(2.5));
        assert_eq!(quantile(&v, 0.25), Some(1.75));
        assert_eq!(quantile(&v, 0.75), Some(3.25));
        assert_eq!(quantile(&[], 0.5), None);
        // Two of five runs unsolved: the median is the third-best run, the upper quartile ∞.
        let s = Spread::of(&[100.0, 300.0, f64::INFINITY, 200.0, f64::INFINITY]).unwrap();
        assert_eq!((s.median, s.q1), (300.0, 200.0));
        assert!(s.q3.is_infinite());
    }

    #[test]
    fn the_interquartile_mean_is_the_mean_of_the_middle_half() {
        // Eight values: the middle four.
        assert_eq!(interquartile_mean(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 100.0]), Some(4.5));
        // Five values: three quarters of the 2nd's and the 4th's shares, all of the 3rd's.
        assert!((interquartile_mean(&[5.0, 1.0, 4.0, 2.0, 3.0]).unwrap() - 3.0).abs() < 1e-12);
        assert_eq!(interquartile_mean(&[7.0]), Some(7.0));
    }

    #[test]
    fn curves_are_banded_at_common_points_and_held_after_they_end() {
        let a = vec![(0.0, 0.0), (10.0, 10.0)];
        let b = vec![(0.0, 0.0), (5.0, 20.0)];
        let c = vec![(0.0, 0.0), (10.0, 0.0)];
        assert_eq!(value_at(&b, 7.5), Some(20.0), "held after its end");
        assert_eq!(value_at(&a, 2.5), Some(2.5));
        let band = band(&[a, b, c], 3);
        assert_eq!(band.len(), 3);
        // At x = 5: 5, 20 and 0 → median 5; at 10: 10, 20, 0 → median 10.
        assert_eq!(band[1], (5.0, 2.5, 5.0, 12.5));
        assert_eq!(band[2].2, 10.0);
    }
}
