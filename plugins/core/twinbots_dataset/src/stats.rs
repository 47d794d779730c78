//! A feature's statistics as LeRobot keeps them (`meta/stats.json`, the episodes' `stats/…`
//! columns): per dimension the minimum, maximum, mean, standard deviation (population, NumPy's
//! `std`), the count of frames and the quantiles LeRobot's normalizers read (`q01` … `q99`).
//! LeRobot estimates quantiles from histograms; these are exact (NumPy's linear interpolation).

use serde_json::{Map, Value, json};

/// The quantiles LeRobot records, and their keys.
pub const QUANTILES: [(f64, &str); 5] = [(0.01, "q01"), (0.10, "q10"), (0.50, "q50"), (0.90, "q90"), (0.99, "q99")];

/// Statistics of one feature over some frames, per dimension.
#[derive(Clone, Debug, PartialEq)]
pub struct FeatureStats {
    pub min: Vec<f64>,
    pub max: Vec<f64>,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    pub count: u64,
    /// In the order of [`QUANTILES`].
    pub quantiles: Vec<Vec<f64>>,
    /// Of a boolean feature (0 and 1): its minimum and maximum are booleans, as NumPy's.
    pub boolean: bool,
}

impl FeatureStats {
    /// Of `values`: rows of `width` values each, row-major (at least one row).
    pub fn of(values: &[f64], width: usize) -> Self {
        let rows = values.len() / width.max(1);
        let mut out = Self {
            min: Vec::with_capacity(width),
            max: Vec::with_capacity(width),
            mean: Vec::with_capacity(width),
            std: Vec::with_capacity(width),
            count: rows as u64,
            quantiles: vec![Vec::with_capacity(width); QUANTILES.len()],
            boolean: false,
        };
        let mut column = Vec::with_capacity(rows);
        for j in 0..width {
            column.clear();
            column.extend((0..rows).map(|i| values[i * width + j]));
            let mean = column.iter().sum::<f64>() / rows as f64;
            let var = column.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / rows as f64;
            column.sort_by(f64::total_cmp);
            out.min.push(column[0]);
            out.max.push(column[rows - 1]);
            out.mean.push(mean);
            out.std.push(var.sqrt());
            for (k, (q, _)) in QUANTILES.iter().enumerate() {
                out.quantiles[k].push(quantile(&column, *q));
            }
        }
        out
    }

    /// The statistics by key, as LeRobot's JSON and episode columns hold them.
    pub fn entries(&self) -> Vec<(&'static str, Vec<f64>)> {
        let mut out = vec![
            ("min", self.min.clone()),
            ("max", self.max.clone()),
            ("mean", self.mean.clone()),
            ("std", self.std.clone()),
        ];
        out.extend(QUANTILES.iter().zip(&self.quantiles).map(|((_, key), v)| (*key, v.clone())));
        out
    }

    /// As `meta/stats.json` holds one feature's.
    pub fn to_json(&self) -> Value {
        let mut map = Map::new();
        for (key, values) in self.entries() {
            let value = match key {
                "min" | "max" if self.boolean => json!(values.iter().map(|&v| v > 0.5).collect::<Vec<_>>()),
                _ => json!(values),
            };
            map.insert(key.into(), value);
        }
        map.insert("count".into(), json!([self.count]));
        Value::Object(map)
    }
}

/// The `q` quantile of sorted values, linearly interpolated between the nearest ranks.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let at = q * (sorted.len() - 1) as f64;
    let (low, high) = (at.floor() as usize, at.ceil() as usize);
    sorted[low] + (sorted[high] - sorted[low]) * (at - low as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_are_numpys_per_dimension() {
        // Two dimensions over five rows: 1..5 and 10, 0, 0, 0, 0.
        let values = [1.0, 10.0, 2.0, 0.0, 3.0, 0.0, 4.0, 0.0, 5.0, 0.0];
        let s = FeatureStats::of(&values, 2);
        assert_eq!((s.min.clone(), s.max.clone(), s.count), (vec![1.0, 0.0], vec![5.0, 10.0], 5));
        assert_eq!(s.mean, vec![3.0, 2.0]);
        // np.std([1,2,3,4,5]) = sqrt(2); np.std([10,0,0,0,0]) = 4.
        assert!((s.std[0] - 2f64.sqrt()).abs() < 1e-15 && (s.std[1] - 4.0).abs() < 1e-15);
        // np.quantile([1,2,3,4,5], [0.01, 0.1, 0.5, 0.9, 0.99]) = 1.04, 1.4, 3, 4.6, 4.96.
        let q: Vec<f64> = s.quantiles.iter().map(|q| q[0]).collect();
        for (got, want) in q.iter().zip([1.04, 1.4, 3.0, 4.6, 4.96]) {
            assert!((got - want).abs() < 1e-12, "{q:?}");
        }
    }
}
