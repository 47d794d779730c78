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
    /// Of an image feature: one value per channel, each as LeRobot keeps an image's (a
    /// `(3, 1, 1)` array of values in [0, 1]).
    pub image: bool,
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
            image: false,
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

    /// Of RGB8 images (each `pixels` × 3 bytes), per channel in [0, 1] as LeRobot gives an
    /// image's: every pixel of every image counted (LeRobot samples and downsizes the frames of
    /// each episode); `count` the images. Exact: a channel's values are 256 levels, so its
    /// quantiles come from their counts.
    pub fn of_images<'a>(images: impl IntoIterator<Item = &'a [u8]>) -> Self {
        let mut levels = [[0u64; 256]; 3];
        let mut count = 0u64;
        for rgb in images {
            count += 1;
            for pixel in rgb.chunks_exact(3) {
                for c in 0..3 {
                    levels[c][pixel[c] as usize] += 1;
                }
            }
        }
        let mut out = Self {
            min: Vec::new(),
            max: Vec::new(),
            mean: Vec::new(),
            std: Vec::new(),
            count,
            quantiles: vec![Vec::new(); QUANTILES.len()],
            boolean: false,
            image: true,
        };
        for counts in &levels {
            let n: u64 = counts.iter().sum();
            let value = |level: usize| level as f64 / 255.0;
            let mean = counts.iter().enumerate().map(|(l, &k)| k as f64 * value(l)).sum::<f64>() / n.max(1) as f64;
            let var = counts.iter().enumerate().map(|(l, &k)| k as f64 * (value(l) - mean).powi(2)).sum::<f64>()
                / n.max(1) as f64;
            // The k-th smallest value (0-based).
            let ranked = |k: u64| {
                let mut seen = 0;
                for (l, &c) in counts.iter().enumerate() {
                    seen += c;
                    if seen > k {
                        return value(l);
                    }
                }
                value(255)
            };
            out.min.push(ranked(0));
            out.max.push(ranked(n.saturating_sub(1)));
            out.mean.push(mean);
            out.std.push(var.sqrt());
            for (k, (q, _)) in QUANTILES.iter().enumerate() {
                let at = q * n.saturating_sub(1) as f64;
                let (low, high) = (ranked(at.floor() as u64), ranked(at.ceil() as u64));
                out.quantiles[k].push(low + (high - low) * (at - at.floor()));
            }
        }
        out
    }

    /// As `meta/stats.json` holds one feature's.
    pub fn to_json(&self) -> Value {
        let mut map = Map::new();
        for (key, values) in self.entries() {
            let value = match key {
                "min" | "max" if self.boolean => json!(values.iter().map(|&v| v > 0.5).collect::<Vec<_>>()),
                _ if self.image => json!(values.iter().map(|&v| [[v]]).collect::<Vec<_>>()),
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
    fn image_statistics_are_numpys_per_channel_in_0_1() {
        // Two images of two pixels: red 0, 255, 51, 102; green all 255; blue 0, 0, 0, 255.
        let a = [0u8, 255, 0, 255, 255, 0];
        let b = [51u8, 255, 0, 102, 255, 255];
        let s = FeatureStats::of_images([&a[..], &b[..]]);
        assert_eq!(s.count, 2);
        let red = [0.0, 1.0, 0.2, 0.4];
        let mean = red.iter().sum::<f64>() / 4.0;
        let std = (red.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 4.0).sqrt();
        assert!((s.mean[0] - mean).abs() < 1e-12 && (s.std[0] - std).abs() < 1e-12, "{s:?}");
        assert_eq!((s.min[0], s.max[0], s.min[1], s.max[1]), (0.0, 1.0, 1.0, 1.0));
        // np.quantile([0, 0.2, 0.4, 1], 0.5) = 0.3; np.quantile([0, 0, 0, 1], 0.99) = 0.97.
        assert!((s.quantiles[2][0] - 0.3).abs() < 1e-12 && (s.quantiles[4][2] - 0.97).abs() < 1e-12, "{s:?}");
        assert_eq!(s.to_json()["mean"][1], json!([[1.0]]));
    }

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
