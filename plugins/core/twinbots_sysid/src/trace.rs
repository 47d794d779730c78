//! A replay's figure as data, made as the replay runs: each series thinned to a bounded
//! envelope ([`Envelope`]), so a replay of any length draws from bounded memory ([`crate::plot`]
//! draws it).

use crate::rig::Reading;

/// The most buckets an [`Envelope`] keeps (two points each).
const MAX_BUCKETS: usize = 1000;

/// A series thinned for a plot as it is made, however long: consecutive samples in buckets,
/// each drawn as its lowest and highest point (in time order), so a spike survives; at most
/// `2 × MAX_BUCKETS` points. A short series (under `MAX_BUCKETS` samples) is drawn whole.
#[derive(Clone, Debug)]
pub struct Envelope {
    /// Samples per bucket: doubles as the series outgrows the buckets.
    width: usize,
    buckets: Vec<[(f64, f64); 2]>,
    /// The bucket being filled, and its samples so far.
    open: Option<([(f64, f64); 2], usize)>,
}

impl Default for Envelope {
    fn default() -> Self {
        Self { width: 1, buckets: Vec::new(), open: None }
    }
}

impl Envelope {
    pub fn push(&mut self, t: f64, v: f64) {
        let (bucket, count) = self.open.get_or_insert(([(t, v); 2], 0));
        if v < bucket[0].1 {
            bucket[0] = (t, v);
        }
        if v > bucket[1].1 {
            bucket[1] = (t, v);
        }
        *count += 1;
        if *count < self.width {
            return;
        }
        self.buckets.push(*bucket);
        self.open = None;
        if self.buckets.len() == MAX_BUCKETS {
            self.buckets = self
                .buckets
                .chunks(2)
                .map(|pair| {
                    let lo = pair.iter().map(|b| b[0]).min_by(|a, b| a.1.total_cmp(&b.1)).expect("a pair");
                    let hi = pair.iter().map(|b| b[1]).max_by(|a, b| a.1.total_cmp(&b.1)).expect("a pair");
                    [lo, hi]
                })
                .collect();
            self.width *= 2;
        }
    }

    /// The points to draw, in time order.
    pub fn points(&self) -> Vec<(f64, f64)> {
        let buckets = self.buckets.iter().chain(self.open.as_ref().map(|(b, _)| b));
        buckets
            .flat_map(|&[lo, hi]| {
                if lo.0 == hi.0 {
                    vec![lo]
                } else if lo.0 < hi.0 {
                    vec![lo, hi]
                } else {
                    vec![hi, lo]
                }
            })
            .collect()
    }
}

/// What a replay figure draws, per joint: the logged position, each twin's, and each twin's
/// error (twin − log), thinned as they are made ([`Envelope`]): a replay of any length draws
/// from bounded memory.
#[derive(Clone, Debug)]
pub struct ReplayPlot {
    /// The log's name, and each twin's label.
    pub log: String,
    pub labels: Vec<String>,
    /// Per joint: the log, then each twin; and each twin's error.
    pub(crate) positions: Vec<Vec<Envelope>>,
    pub(crate) errors: Vec<Vec<Envelope>>,
}

impl ReplayPlot {
    pub fn new(log: &str, labels: &[&str], joints: usize) -> Self {
        let twins = labels.len();
        Self {
            log: log.to_string(),
            labels: labels.iter().map(|l| l.to_string()).collect(),
            positions: vec![vec![Envelope::default(); twins + 1]; joints],
            errors: vec![vec![Envelope::default(); twins]; joints],
        }
    }

    /// One time: the logged positions, and each twin's reading with its encoder biases.
    pub fn push(&mut self, time: f64, logged: &[f32], twins: &[(&Reading, &[f64])]) {
        for (j, row) in self.positions.iter_mut().enumerate() {
            let log = logged[j] as f64;
            row[0].push(time, log);
            for (i, (reading, bias)) in twins.iter().enumerate() {
                let twin = reading.position[j] as f64 + bias[j];
                row[i + 1].push(time, twin);
                self.errors[j][i].push(time, twin - log);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A short series is drawn as it is; a long one in at most 2 × MAX_BUCKETS points, its
    /// single-sample spike and its ends kept, in time order.
    #[test]
    fn an_envelope_keeps_short_series_whole_and_a_long_ones_spike() {
        let mut short = Envelope::default();
        let points: Vec<(f64, f64)> = (0..500).map(|k| (k as f64, (k as f64 * 0.1).sin())).collect();
        points.iter().for_each(|&(t, v)| short.push(t, v));
        assert_eq!(short.points(), points);

        let mut long = Envelope::default();
        for k in 0..1_000_003 {
            long.push(k as f64, if k == 654_321 { 9.0 } else { (k as f64 * 1e-3).sin() });
        }
        let drawn = long.points();
        assert!(drawn.len() <= 2 * MAX_BUCKETS, "{}", drawn.len());
        assert!(drawn.contains(&(654_321.0, 9.0)));
        assert!(drawn.windows(2).all(|w| w[0].0 < w[1].0));
        assert_eq!(drawn.first().unwrap().0, 0.0);
        assert!(drawn.last().unwrap().0 >= 1_000_000.0, "{:?}", drawn.last());
    }
}
