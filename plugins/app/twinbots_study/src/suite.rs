//! A policy test suite (`twinbots study <robot> SUITE.toml`): the paper repository's test
//! orchestrator for its pendulums as a TOML file. Step-response kicks, impulse disturbances
//! and payload variations, each run for every controller and seed (docs/studies.md).

use std::path::Path;

use serde::Deserialize;

/// The largest push a suite may ask for (N).
pub const MAX_FORCE: f64 = 1e6;
/// The most runs of one controller (tests × seeds), each an arena stepping beside the others.
pub const MAX_RUNS: usize = 1024;
/// The longest a run may last (s).
pub const MAX_DURATION: f64 = 600.0;
/// The suite file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Suite {
    /// The robot the suite is written for (checked against the command's robot).
    pub robot: Option<String>,
    /// Length of each run (s).
    #[serde(default = "default_duration")]
    pub duration: f64,
    /// The observation term the figures read (a pendulum's `pole_angle`).
    pub signal: String,
    #[serde(default)]
    pub setpoint: f64,
    /// Settled once |signal − set point| stays within this (the signal's units).
    pub settle_band: f64,
    /// The steady-state error averages the record's last `window` seconds.
    #[serde(default = "default_window")]
    pub window: f64,
    /// One run per seed for every test and controller.
    #[serde(default = "default_seeds")]
    pub seeds: Vec<u64>,
    /// `classic` (the robot's feedback controller), a run directory of `twinbots train`, or an
    /// `.onnx` file of `twinbots export`; relative paths from the suite file's folder.
    #[serde(default = "default_controllers")]
    pub controllers: Vec<String>,
    /// Where pushes act.
    pub push: PushSite,
    pub step_response: Option<StepResponse>,
    pub impulse: Option<Impulse>,
    pub payload: Option<Payload>,
}

/// The link pushes act on, where, and which way.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushSite {
    pub link: String,
    /// In the link frame (m).
    #[serde(default)]
    pub point: [f32; 3],
    /// Direction of a positive force, arena frame (normalised).
    pub direction: [f32; 3],
}

/// `[step_response]`: a kick of each force for a few control steps.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepResponse {
    /// N.
    pub forces: Vec<f64>,
    /// When (s).
    #[serde(default = "default_at")]
    pub at: f64,
    #[serde(default = "default_kick_steps")]
    pub control_steps: u32,
}

/// `[impulse]`: each force at each time, for `duration` seconds.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Impulse {
    pub forces: Vec<f64>,
    pub at: Vec<f64>,
    #[serde(default = "default_impulse_duration")]
    pub duration: f64,
}

/// `[payload]`: runs with the link's mass made each of these (kg), no push: the response is
/// to the episode's own start.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Payload {
    /// The link whose mass changes; default the push link.
    pub link: Option<String>,
    pub mass: Vec<f64>,
}

fn default_duration() -> f64 {
    10.0
}
fn default_window() -> f64 {
    1.0
}
fn default_seeds() -> Vec<u64> {
    vec![0]
}
fn default_controllers() -> Vec<String> {
    vec!["classic".into()]
}
fn default_at() -> f64 {
    2.0
}
fn default_kick_steps() -> u32 {
    2
}
fn default_impulse_duration() -> f64 {
    0.1
}

/// One test of the suite: a push (force along the site's direction, from `at`, for `seconds`)
/// or a payload.
#[derive(Clone, Debug, PartialEq)]
pub enum Test {
    Push { force: f64, at: f64, seconds: f64 },
    Payload { link: String, mass: f64 },
}

/// A named test.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedTest {
    /// A file-name-safe name: `step-20N`, `impulse-30N-at-2s`, `payload-0.05kg`.
    pub name: String,
    /// `step_response`, `impulse`, `payload`.
    pub kind: &'static str,
    pub test: Test,
}

impl Suite {
    /// Reads and checks a suite file; every error names the file and the key.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let suite: Self = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        suite.check().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(suite)
    }

    fn check(&self) -> Result<(), String> {
        let positive = |key: &str, v: f64| {
            if v > 0.0 && v.is_finite() { Ok(()) } else { Err(format!("{key} = {v}: must be a positive number")) }
        };
        positive("duration", self.duration)?;
        positive("settle_band", self.settle_band)?;
        positive("window", self.window)?;
        if self.window > self.duration {
            return Err(format!("window = {} s is longer than duration = {} s", self.window, self.duration));
        }
        if self.seeds.is_empty() {
            return Err("seeds = []: give at least one".into());
        }
        if self.duration > MAX_DURATION {
            return Err(format!("duration = {} s: a run lasts at most {MAX_DURATION} s", self.duration));
        }
        // Every run of a controller steps side by side, an arena each.
        let tests = self.step_response.as_ref().map_or(0, |s| s.forces.len())
            + self.impulse.as_ref().map_or(0, |i| i.forces.len() * i.at.len())
            + self.payload.as_ref().map_or(0, |p| p.mass.len());
        let runs = tests.saturating_mul(self.seeds.len());
        if runs > MAX_RUNS {
            return Err(format!(
                "{tests} tests × {} seeds = {runs} runs a controller: at most {MAX_RUNS} (they step side by side)",
                self.seeds.len()
            ));
        }
        if self.controllers.is_empty() {
            return Err("controllers = []: give at least one (classic, a run directory or an .onnx file)".into());
        }
        let d = self.push.direction;
        if !(d.iter().all(|v| v.is_finite()) && d.iter().map(|v| v * v).sum::<f32>() > 0.0) {
            return Err(format!("push.direction = {d:?}: must be a non-zero vector"));
        }
        let within = |key: &str, at: f64| {
            if (0.0..self.duration).contains(&at) {
                Ok(())
            } else {
                Err(format!("{key} = {at} s: must lie in [0, duration = {} s)", self.duration))
            }
        };
        let finite = |key: &str, values: &[f64]| match values.iter().find(|v| !v.is_finite()) {
            _ if values.is_empty() => Err(format!("{key} = []: give at least one value, or leave the table out")),
            Some(v) => Err(format!("{key} contains {v}")),
            None => Ok(()),
        };
        // A push past a meganewton is beyond any cell, and beyond what the physics takes (at
        // 1e30 N its solver dropped the push and the run "survived").
        let forces = |key: &str, values: &[f64]| match values.iter().find(|v| v.abs() > MAX_FORCE) {
            Some(v) => Err(format!("{key} contains {v:e} N: a push is at most {MAX_FORCE:e} N")),
            None => finite(key, values),
        };
        if let Some(s) = &self.step_response {
            forces("step_response.forces", &s.forces)?;
            within("step_response.at", s.at)?;
            if s.control_steps == 0 {
                return Err("step_response.control_steps = 0: a kick lasts at least one control step".into());
            }
        }
        if let Some(i) = &self.impulse {
            forces("impulse.forces", &i.forces)?;
            finite("impulse.at", &i.at)?;
            for &at in &i.at {
                within("impulse.at", at)?;
            }
            positive("impulse.duration", i.duration)?;
        }
        if let Some(p) = &self.payload {
            finite("payload.mass", &p.mass)?;
            if let Some(m) = p.mass.iter().find(|&&m| m < 0.0) {
                return Err(format!("payload.mass contains {m}: a mass is at least 0 kg"));
            }
        }
        if self.step_response.is_none() && self.impulse.is_none() && self.payload.is_none() {
            return Err("no tests: give [step_response], [impulse] or [payload]".into());
        }
        Ok(())
    }

    /// Every test, in file order: step responses, impulses (by force, then time), payloads.
    pub fn tests(&self, control_dt: f64) -> Vec<NamedTest> {
        let mut tests = Vec::new();
        if let Some(s) = &self.step_response {
            for &force in &s.forces {
                let test = Test::Push { force, at: s.at, seconds: f64::from(s.control_steps) * control_dt };
                tests.push(NamedTest { name: format!("step-{}N", number(force)), kind: "step_response", test });
            }
        }
        if let Some(i) = &self.impulse {
            for &force in &i.forces {
                for &at in &i.at {
                    let test = Test::Push { force, at, seconds: i.duration };
                    tests.push(NamedTest {
                        name: format!("impulse-{}N-at-{}s", number(force), number(at)),
                        kind: "impulse",
                        test,
                    });
                }
            }
        }
        if let Some(p) = &self.payload {
            let link = p.link.clone().unwrap_or_else(|| self.push.link.clone());
            for &mass in &p.mass {
                tests.push(NamedTest {
                    name: format!("payload-{}kg", number(mass)),
                    kind: "payload",
                    test: Test::Payload { link: link.clone(), mass },
                });
            }
        }
        tests
    }
}

/// A number as a file name reads it: `20`, `0.05`, `-30`.
fn number(v: f64) -> String {
    format!("{v}")
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASE: &str =
        "signal = \"pole_angle\"\nsettle_band = 0.02\n[push]\nlink = \"pole_tip\"\ndirection = [1, 0, 0]\n";

    /// Top-level keys go before the base's tables, anything else after them.
    fn parse(extra: &str) -> Result<Suite, String> {
        let split = extra
            .match_indices('[')
            .map(|(i, _)| i)
            .find(|&i| i == 0 || extra[..i].ends_with('\n'))
            .unwrap_or(extra.len());
        let (top, tables) = extra.split_at(split);
        let suite: Suite = toml::from_str(&format!("{top}{BASE}{tables}")).map_err(|e| e.to_string())?;
        suite.check().map(|_| suite)
    }

    #[test]
    fn tables_expand_into_named_tests() {
        let suite = parse(
            "[step_response]\nforces = [20, 40]\n[impulse]\nforces = [30]\nat = [2, 4.5]\n[payload]\nmass = [0.05]\n",
        )
        .unwrap();
        let names: Vec<String> = suite.tests(0.032).into_iter().map(|t| t.name).collect();
        assert_eq!(names, ["step-20N", "step-40N", "impulse-30N-at-2s", "impulse-30N-at-4.5s", "payload-0.05kg"]);
        assert_eq!(suite.tests(0.032)[0].test, Test::Push { force: 20.0, at: 2.0, seconds: 0.064 });
    }

    #[test]
    fn bad_suites_name_the_key() {
        for (extra, expected) in [
            ("", "no tests"),
            ("[step_response]\nforces = []\n", "step_response.forces = []"),
            ("[impulse]\nforces = [30]\nat = [12]\n", "impulse.at = 12 s"),
            ("[payload]\nmass = [-1]\n", "payload.mass contains -1"),
            ("[payload]\nmas = [1]\n", "unknown field `mas`"),
            ("duration = -1\n[payload]\nmass = [1]\n", "duration = -1"),
            ("controllers = []\n[payload]\nmass = [1]\n", "controllers = []"),
        ] {
            let err = parse(extra).expect_err(extra);
            assert!(err.contains(expected), "{extra:?}: {err}");
        }
    }
}
