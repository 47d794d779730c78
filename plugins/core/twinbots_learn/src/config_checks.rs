//! The range checks of the learners' settings: each error names the setting as the settings file
//! spells it (`<algorithm>.<key> = value: must be …`), so that nonsense never reaches a learner.

use std::fmt::Display;

/// The checks of one algorithm's table (`Checks("sac")`).
pub struct Checks(pub &'static str);

impl Checks {
    /// An error naming `key` and its `value` unless `ok`.
    pub fn check(&self, key: &str, value: impl Display, ok: bool, allowed: &str) -> anyhow::Result<()> {
        anyhow::ensure!(ok, "{}.{key} = {value}: must be {allowed}", self.0);
        Ok(())
    }

    pub fn positive(&self, key: &str, v: f64) -> anyhow::Result<()> {
        self.check(key, v, v.is_finite() && v > 0.0, "a finite number > 0")
    }

    pub fn non_negative(&self, key: &str, v: f64) -> anyhow::Result<()> {
        self.check(key, v, v.is_finite() && v >= 0.0, "a finite number ≥ 0")
    }

    /// A whole number in `1..=max`: the upper bound keeps a typo from asking for memory or time no
    /// machine has.
    pub fn count(&self, key: &str, v: usize, max: usize) -> anyhow::Result<()> {
        self.check(key, v, (1..=max).contains(&v), &format!("a whole number in 1..={max}"))
    }

    /// A discount or a Polyak coefficient: in (0, 1].
    pub fn fraction(&self, key: &str, v: f32) -> anyhow::Result<()> {
        self.check(key, v, v > 0.0 && v <= 1.0, "in (0, 1]")
    }

    /// The hidden layers of an MLP.
    pub fn hidden(&self, sizes: &[usize]) -> anyhow::Result<()> {
        let ok = (1..=16).contains(&sizes.len()) && sizes.iter().all(|&n| (1..=4096).contains(&n));
        self.check("hidden", format!("{sizes:?}"), ok, "1 to 16 layer sizes, each in 1..=4096")
    }
}
