//! A cell study file (`twinbots study ur5e STUDY.toml`, docs/studies.md): the layouts, the
//! factors and the failure scenarios swept, and their combinations.

use std::path::Path;

use serde::Deserialize;
use twinbots_task::cell::layout::CellLayout;

/// The study file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellStudy {
    pub robot: Option<String>,
    /// Episodes per combination.
    #[serde(default = "default_episodes")]
    pub episodes: usize,
    #[serde(default)]
    pub seed: u64,
    /// `classic`, run directories, `.onnx` files (relative to the study file).
    #[serde(default = "default_controllers")]
    pub controllers: Vec<String>,
    /// The layouts (default: the robot's default cell alone).
    #[serde(default, rename = "layout")]
    pub layouts: Vec<LayoutVariant>,
    #[serde(default)]
    pub factors: Factors,
    /// The push scenarios' push.
    #[serde(default)]
    pub push: PushScenario,
    /// The sensor dropout scenario's window.
    #[serde(default)]
    pub dropout: Dropout,
}

/// A layout: a file, or the default cell with some entries changed.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayoutVariant {
    pub name: String,
    /// A layout file (docs/cells.md), relative to the study file.
    pub file: Option<String>,
    /// The pick fixture's, the place fixture's and the robot's position (m), the robot's yaw (°).
    pub pick: Option<[f32; 2]>,
    pub place: Option<[f32; 2]>,
    pub robot: Option<[f32; 2]>,
    pub yaw: Option<f32>,
}

/// `[factors]`: each a list of levels, swept in full.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Factors {
    /// The controller's speed slider: fractions of every commanded joint speed, (0, 1].
    #[serde(default = "default_speed")]
    pub speed: Vec<f32>,
    /// The part's mass (kg); none: the part as its URDF makes it.
    #[serde(default)]
    pub payload: Vec<f64>,
    /// Control steps between the controller's command and the arm receiving it.
    #[serde(default = "default_latency")]
    pub latency: Vec<u32>,
    /// Failure scenarios: none, push-tool, push-part, sensor-dropout, failed-grasp.
    #[serde(default = "default_failure")]
    pub failure: Vec<String>,
}

impl Default for Factors {
    fn default() -> Self {
        Self { speed: default_speed(), payload: Vec::new(), latency: default_latency(), failure: default_failure() }
    }
}

/// `[push]`: the push of `push-tool` (on the tool's flange) and `push-part`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushScenario {
    /// N, cell frame.
    #[serde(default = "default_push_force")]
    pub force: [f32; 3],
    /// s into each episode.
    #[serde(default = "default_push_at")]
    pub at: f64,
    #[serde(default = "default_push_duration")]
    pub duration: f64,
}

impl Default for PushScenario {
    fn default() -> Self {
        Self { force: default_push_force(), at: default_push_at(), duration: default_push_duration() }
    }
}

/// `[dropout]`: the controller's readings freeze at `at` (s into each episode) for `duration`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dropout {
    #[serde(default = "default_dropout_at")]
    pub at: f64,
    #[serde(default = "default_dropout_duration")]
    pub duration: f64,
}

impl Default for Dropout {
    fn default() -> Self {
        Self { at: default_dropout_at(), duration: default_dropout_duration() }
    }
}

fn default_episodes() -> usize {
    4
}
fn default_controllers() -> Vec<String> {
    vec!["classic".into()]
}
fn default_speed() -> Vec<f32> {
    vec![1.0]
}
fn default_latency() -> Vec<u32> {
    vec![0]
}
fn default_failure() -> Vec<String> {
    vec!["none".into()]
}
fn default_push_force() -> [f32; 3] {
    [0.0, 100.0, 0.0]
}
fn default_push_at() -> f64 {
    3.0
}
fn default_push_duration() -> f64 {
    0.2
}
fn default_dropout_at() -> f64 {
    3.0
}
fn default_dropout_duration() -> f64 {
    0.5
}

/// A failure scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Failure {
    None,
    PushTool,
    PushPart,
    SensorDropout,
    FailedGrasp,
}

impl Failure {
    pub const ALL: [Failure; 5] =
        [Failure::None, Failure::PushTool, Failure::PushPart, Failure::SensorDropout, Failure::FailedGrasp];

    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::PushTool => "push-tool",
            Self::PushPart => "push-part",
            Self::SensorDropout => "sensor-dropout",
            Self::FailedGrasp => "failed-grasp",
        }
    }

    fn parse(name: &str) -> Result<Self, String> {
        Self::ALL.into_iter().find(|f| f.name() == name).ok_or_else(|| {
            format!(
                "factors.failure: unknown scenario '{name}'; the scenarios: {}",
                Self::ALL.map(Failure::name).join(", ")
            )
        })
    }
}

/// One combination of the sweep: its levels, and the layout it runs in.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    pub controller: usize,
    pub layout: usize,
    pub speed: f32,
    pub payload: Option<f64>,
    pub latency: u32,
    pub failure: Failure,
}

impl CellStudy {
    /// Reads and checks a study file; errors name the file and the entry.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let study: Self = toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        study.check().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Ok(study)
    }

    fn check(&self) -> Result<(), String> {
        if self.episodes == 0 {
            return Err("episodes = 0: at least one per combination".into());
        }
        if self.controllers.is_empty() {
            return Err("controllers = []: give at least one (classic, a run directory or an .onnx file)".into());
        }
        let f = &self.factors;
        for (key, empty) in [
            ("factors.speed", f.speed.is_empty()),
            ("factors.latency", f.latency.is_empty()),
            ("factors.failure", f.failure.is_empty()),
        ] {
            if empty {
                return Err(format!("{key} = []: give at least one level, or leave it out"));
            }
        }
        if let Some(s) = f.speed.iter().find(|s| !(**s > 0.0 && **s <= 1.0)) {
            return Err(format!("factors.speed contains {s}: a speed slider lies in (0, 1]"));
        }
        if let Some(m) = f.payload.iter().find(|m| !(**m > 0.0 && m.is_finite())) {
            return Err(format!("factors.payload contains {m}: a part's mass is positive (kg)"));
        }
        if let Some(l) = f.latency.iter().find(|l| **l > 50) {
            return Err(format!("factors.latency contains {l}: at most 50 control steps (2 s)"));
        }
        for name in &f.failure {
            Failure::parse(name)?;
        }
        for (key, at, duration) in
            [("push", self.push.at, self.push.duration), ("dropout", self.dropout.at, self.dropout.duration)]
        {
            if !(at >= 0.0 && at.is_finite()) {
                return Err(format!("{key}.at = {at}: must be a time ≥ 0 (s)"));
            }
            if !(duration > 0.0 && duration.is_finite()) {
                return Err(format!("{key}.duration = {duration}: must be positive (s)"));
            }
        }
        let mut names: Vec<&str> = Vec::new();
        for (i, l) in self.layouts.iter().enumerate() {
            if names.contains(&l.name.as_str()) || l.name.is_empty() || l.name.contains(['/', '\\', ',']) {
                return Err(format!(
                    "layout[{i}].name = '{}': names are distinct, non-empty, without / \\ or ,",
                    l.name
                ));
            }
            names.push(&l.name);
        }
        Ok(())
    }

    /// The layouts, each checked as a layout file is (errors name the study file's entry):
    /// `default` (the robot's own cell) changed by each entry's keys.
    pub fn layouts(&self, base: &Path, default: &CellLayout) -> anyhow::Result<Vec<(String, CellLayout)>> {
        if self.layouts.is_empty() {
            return Ok(vec![("default".into(), default.clone())]);
        }
        self.layouts
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let entry = format!("layout[{i}] ('{}')", v.name);
                let mut layout = match &v.file {
                    Some(file) => CellLayout::read(&base.join(file)).map_err(|e| anyhow::anyhow!("{entry}: {e}"))?,
                    None => default.clone(),
                };
                if let Some(p) = v.pick {
                    layout.pick.position = p;
                }
                if let Some(p) = v.place {
                    layout.place.position = p;
                }
                if let Some(p) = v.robot {
                    layout.robot.position = p;
                }
                if let Some(y) = v.yaw {
                    layout.robot.yaw = y;
                }
                layout.check().map_err(|e| anyhow::anyhow!("{entry}: {e}"))?;
                Ok((v.name.clone(), layout))
            })
            .collect()
    }

    /// Every combination: controllers × layouts × speeds × payloads × latencies × failures, in
    /// that order of nesting (the last varies fastest).
    pub fn combinations(&self, controllers: usize, layouts: usize) -> Vec<Combination> {
        let f = &self.factors;
        let payloads: Vec<Option<f64>> =
            if f.payload.is_empty() { vec![None] } else { f.payload.iter().copied().map(Some).collect() };
        let failures: Vec<Failure> = f.failure.iter().map(|n| Failure::parse(n).expect("checked on reading")).collect();
        let mut out = Vec::new();
        for controller in 0..controllers {
            for layout in 0..layouts {
                for &speed in &f.speed {
                    for &payload in &payloads {
                        for &latency in &f.latency {
                            for &failure in &failures {
                                out.push(Combination { controller, layout, speed, payload, latency, failure });
                            }
                        }
                    }
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<CellStudy, String> {
        let study: CellStudy = toml::from_str(text).map_err(|e| e.to_string())?;
        study.check().map(|_| study)
    }

    #[test]
    fn factors_sweep_in_full() {
        let study = parse("[[layout]]\nname = \"a\"\n[[layout]]\nname = \"b\"\nplace = [-0.3, -0.45]\n[factors]\nspeed = [1.0, 0.5]\nfailure = [\"none\", \"failed-grasp\"]\n").unwrap();
        let combos = study.combinations(1, 2);
        assert_eq!(combos.len(), 2 * 2 * 2);
        assert_eq!(combos[1].failure, Failure::FailedGrasp);
        assert_eq!(combos[2].speed, 0.5);
        let layouts = study.layouts(Path::new("."), &CellLayout::default()).unwrap();
        assert_eq!(layouts[1].1.place.position, [-0.3, -0.45]);
    }

    #[test]
    fn bad_studies_name_the_entry() {
        for (text, expected) in [
            ("[factors]\ntemperature = [20]\n", "unknown field `temperature`"),
            ("[factors]\nfailure = [\"fire\"]\n", "unknown scenario 'fire'; the scenarios: none, push-tool"),
            ("[factors]\nspeed = [1.5]\n", "factors.speed contains 1.5"),
            ("[factors]\npayload = [0]\n", "factors.payload contains 0"),
            ("episodes = 0\n", "episodes = 0"),
            ("[[layout]]\nname = \"x\"\n[[layout]]\nname = \"x\"\n", "layout[1].name = 'x'"),
        ] {
            let err = parse(text).expect_err(text);
            assert!(err.contains(expected), "{text}: {err}");
        }
        let study = parse("[[layout]]\nname = \"off\"\nplace = [-1.2, 0.0]\n").unwrap();
        let err = study.layouts(Path::new("."), &CellLayout::default()).unwrap_err().to_string();
        assert!(
            err.contains(
                "layout[0] ('off'): place.position = [-1.2, 0.0]: the fixture's 12 cm plate leaves the table top"
            ),
            "{err}"
        );
    }
}
