//! Calibration and truth files, owned by [`Calibration`]: TOML with a `[parameters]` table of
//! `name = value` (SI units, the names `twinbots identify <robot> --list-params` prints), and what
//! `twinbots identify` says of them: `[fit]` (the logs, the tracking errors, the search's cost),
//! `[spread]` (each fitted value's standard deviation, same names and units, which domain
//! randomization can draw around the fit with: `randomization.calibration_spread`) and
//! `[not_identifiable]` (the parameters the logs could not pin down, each with why). A name holds
//! dots (`elbow_joint.damping`); written bare, TOML reads it as a dotted key (a nested table),
//! quoted as one key: both read the same.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};
use twinbots_sim::{ParameterSpec, Parameters};

/// A calibration file, whole.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Calibration {
    /// `[parameters]`: the values over the twin's nominal ones.
    pub parameters: Parameters,
    /// `[spread]`: each fitted value's standard deviation (none in a hand-written file).
    pub spread: Parameters,
    /// `[not_identifiable]`: the fitted parameters the logs did not pin down, each with why.
    pub not_identifiable: BTreeMap<String, String>,
    /// `[fit]`: how `identify` arrived at the values (none in a hand-written file).
    pub fit: Option<FitRecord>,
}

/// A calibration's `[fit]` table.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct FitRecord {
    pub robot: String,
    /// The twinbots version that fitted it.
    pub twinbots: String,
    /// The logs fitted.
    pub logs: Vec<String>,
    /// χ² per step of the twin with the starting values, and with the fitted ones.
    pub tracking_error_nominal: f64,
    pub tracking_error_calibrated: f64,
    /// The replay's own numerical noise in χ².
    pub replay_noise: f64,
    pub candidates: u64,
    pub seconds: f64,
    /// The joint-position RMSE (rad) on held-out logs, when `--validate` gave some.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_position_rmse_nominal: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub validation_position_rmse_calibrated: Option<f64>,
}

impl Calibration {
    /// Reads a calibration's TOML text, unchecked against any robot; the error names the entry at
    /// fault.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let table: toml::Table = toml::from_str(text).map_err(|e| anyhow::anyhow!("not valid TOML: {e}"))?;
        let parameters = values_of(&table, "parameters")?.ok_or_else(|| anyhow::anyhow!("no [parameters] table"))?;
        let spread = values_of(&table, "spread")?.unwrap_or_default();
        let not_identifiable = match table.get("not_identifiable") {
            None => BTreeMap::new(),
            Some(value) => value.clone().try_into().map_err(|e| anyhow::anyhow!("[not_identifiable]: {e}"))?,
        };
        let fit = match table.get("fit") {
            None => None,
            Some(value) => Some(value.clone().try_into().map_err(|e| anyhow::anyhow!("[fit]: {e}"))?),
        };
        Ok(Self { parameters, spread, not_identifiable, fit })
    }

    /// Reads a calibration (or truth) file, checked against the robot's parameters: every name
    /// one of them, every spread one of the file's parameters and finite and ≥ 0. Errors name
    /// the file.
    pub fn read(path: &Path, catalogue: &[ParameterSpec], robot: &str) -> anyhow::Result<Self> {
        let in_file = || format!("calibration {}", path.display());
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", in_file()))?;
        let calibration = Self::parse(&text).with_context(in_file)?;
        calibration.parameters.check(catalogue, robot).map_err(|e| anyhow::anyhow!("{}: {e}", in_file()))?;
        for (name, sigma) in &calibration.spread.0 {
            anyhow::ensure!(
                calibration.parameters.0.contains_key(name),
                "{}: [spread] names '{name}', which its [parameters] do not set",
                in_file()
            );
            anyhow::ensure!(
                sigma.is_finite() && *sigma >= 0.0,
                "{}: [spread] '{name}' = {sigma}: must be finite and ≥ 0",
                in_file()
            );
        }
        Ok(calibration)
    }

    /// [`Calibration::read`] of the file, if one is given (none: no parameters).
    pub fn read_optional(path: Option<&Path>, catalogue: &[ParameterSpec], robot: &str) -> anyhow::Result<Self> {
        path.map_or(Ok(Self::default()), |path| Self::read(path, catalogue, robot))
    }

    /// The file's text: `[parameters]` (quoted names, in the catalogue's order, each with its
    /// unit), then `[fit]`, `[spread]` and `[not_identifiable]` where there are any.
    pub fn to_text(&self, catalogue: &[ParameterSpec]) -> String {
        let mut text = String::from("[parameters]\n");
        let params = &self.parameters;
        let ordered = catalogue.iter().filter_map(|p| params.get(&p.name).map(|v| (p.name.as_str(), v, p.unit)));
        for (name, value, unit) in ordered {
            text += &format!("\"{name}\" = {value:e} # {unit}\n");
        }
        for (name, value) in params.0.iter().filter(|(n, _)| !catalogue.iter().any(|p| &p.name == *n)) {
            text += &format!("\"{name}\" = {value:e}\n");
        }
        let mut metadata = toml::Table::new();
        if let Some(fit) = &self.fit {
            metadata.insert("fit".into(), toml::Value::try_from(fit).expect("a fit record serialises"));
        }
        if !self.spread.0.is_empty() {
            let spread = self.spread.0.iter().map(|(n, v)| (n.clone(), (*v).into())).collect();
            metadata.insert("spread".into(), toml::Value::Table(spread));
        }
        if !self.not_identifiable.is_empty() {
            let flags = self.not_identifiable.iter().map(|(n, why)| (n.clone(), why.clone().into())).collect();
            metadata.insert("not_identifiable".into(), toml::Value::Table(flags));
        }
        if !metadata.is_empty() {
            text += "\n";
            text += &toml::to_string(&metadata).expect("a TOML table serialises");
        }
        text
    }

    /// Writes the file atomically (whole or not at all).
    pub fn write(&self, path: &Path, catalogue: &[ParameterSpec]) -> anyhow::Result<()> {
        twinbots_api::files::write_atomic(path, self.to_text(catalogue).as_bytes())
            .with_context(|| path.display().to_string())
    }
}

/// The table `name` of a calibration, flattened to dotted names (none: absent).
fn values_of(table: &toml::Table, name: &str) -> anyhow::Result<Option<Parameters>> {
    let Some(values) = table.get(name) else { return Ok(None) };
    let toml::Value::Table(values) = values else { bail!("'{name}' is not a table") };
    let mut out = Parameters::default();
    flatten("", values, &mut out)?;
    Ok(Some(out))
}

fn flatten(prefix: &str, table: &toml::Table, out: &mut Parameters) -> anyhow::Result<()> {
    for (key, value) in table {
        let name = if prefix.is_empty() { key.clone() } else { format!("{prefix}.{key}") };
        match value {
            toml::Value::Table(inner) => flatten(&name, inner, out)?,
            toml::Value::Float(v) => _ = out.0.insert(name, *v),
            toml::Value::Integer(v) => _ = out.0.insert(name, *v as f64),
            other => bail!("parameter '{name}' is {other}, not a number"),
        }
    }
    Ok(())
}

/// Puts `params` over the twin's parameters in an app not yet started (its start-up applies
/// them to every arena).
pub fn calibrate(app: &mut bevy::prelude::App, params: &Parameters) {
    if params.0.is_empty() {
        return;
    }
    let world = app.world_mut();
    match world.get_resource_mut::<Parameters>() {
        Some(mut current) => current.extend(params),
        None => world.insert_resource(params.clone()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dotted_and_quoted_names_read_the_same() {
        let parse = |text: &str| Calibration::parse(text).map(|c| c.parameters);
        let a = parse("[parameters]\nelbow.damping = 2\ncommand_delay = 0.012\n").unwrap();
        let b = parse("[parameters]\n\"elbow.damping\" = 2.0\n\"command_delay\" = 1.2e-2\n").unwrap();
        assert_eq!(a, b);
        assert_eq!(a.get("elbow.damping"), Some(2.0));
        let err = parse("[parameters]\nelbow.damping = 'high'\n").unwrap_err().to_string();
        assert!(err.contains("'elbow.damping'"), "{err}");
        assert!(parse("[fit]\n").unwrap_err().to_string().contains("no [parameters]"));
        assert_eq!(Calibration::parse("[parameters]\nx = 1\n").unwrap().spread, Parameters::default());
        let spread = Calibration::parse("[parameters]\n[spread]\n\"elbow.damping\" = 0.5\n").unwrap().spread;
        assert_eq!(spread.get("elbow.damping"), Some(0.5));
        let err = Calibration::parse("[parameters]\n[fit]\ncandidates = 'many'\n").unwrap_err().to_string();
        assert!(err.starts_with("[fit]"), "{err}");
    }

    #[test]
    fn a_whole_file_reads_back_as_written() {
        let calibration = Calibration {
            parameters: Parameters([("a.damping".to_string(), 1.5), ("b".to_string(), 2e-3)].into()),
            spread: Parameters([("a.damping".to_string(), 0.25)].into()),
            not_identifiable: [("b".to_string(), "the logs do not move it".to_string())].into(),
            fit: Some(FitRecord {
                robot: "ur5e".into(),
                logs: vec!["fit.mcap".into()],
                candidates: 120,
                validation_position_rmse_nominal: Some(0.01),
                ..Default::default()
            }),
        };
        let catalogue = [ParameterSpec {
            name: "a.damping".into(),
            kind: twinbots_sim::ParameterKind::Damping,
            joint: Some("a".into()),
            default: 1.0,
            unit: "N m s/rad",
        }];
        let text = calibration.to_text(&catalogue);
        assert!(text.starts_with("[parameters]\n\"a.damping\" = 1.5e0 # N m s/rad\n"), "{text}");
        assert_eq!(Calibration::parse(&text).unwrap(), calibration, "{text}");
    }
}
