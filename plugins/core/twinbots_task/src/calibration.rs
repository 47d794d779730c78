//! Calibration and truth files: TOML with a `[parameters]` table of `name = value` (SI units,
//! the names `twinbots identify <robot> --list-params` prints) and any other tables of
//! metadata. A name holds dots (`elbow_joint.damping`); written bare, TOML reads it as a dotted
//! key (a nested table), quoted as one key: both read the same.

use std::path::Path;

use anyhow::{Context, bail};
use twinbots_sim::{ParameterSpec, Parameters};

/// Reads the `[parameters]` of a calibration's TOML text; the error names the entry at fault.
pub fn parse_parameters(text: &str) -> anyhow::Result<Parameters> {
    let table: toml::Table = toml::from_str(text).map_err(|e| anyhow::anyhow!("not valid TOML: {e}"))?;
    let Some(parameters) = table.get("parameters") else { bail!("no [parameters] table") };
    let toml::Value::Table(parameters) = parameters else { bail!("'parameters' is not a table") };
    let mut out = Parameters::default();
    flatten("", parameters, &mut out)?;
    Ok(out)
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

/// Reads a calibration (or truth) file and checks its names against the robot's parameters;
/// errors name the file.
pub fn read_calibration(path: &Path, catalogue: &[ParameterSpec], robot: &str) -> anyhow::Result<Parameters> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read calibration {}", path.display()))?;
    let params = parse_parameters(&text).with_context(|| format!("calibration {}", path.display()))?;
    params.check(catalogue, robot).map_err(|e| anyhow::anyhow!("calibration {}: {e}", path.display()))?;
    Ok(params)
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
        None => _ = world.insert_resource(params.clone()),
    }
}

/// A calibration file's text: `[parameters]` (quoted names, in the catalogue's order) and the
/// metadata tables given.
pub fn calibration_text(params: &Parameters, catalogue: &[ParameterSpec], metadata: &toml::Table) -> String {
    let mut text = String::from("[parameters]\n");
    let ordered = catalogue.iter().filter_map(|p| params.get(&p.name).map(|v| (p.name.as_str(), v, p.unit)));
    for (name, value, unit) in ordered {
        text += &format!("\"{name}\" = {value:e} # {unit}\n");
    }
    for (name, value) in params.0.iter().filter(|(n, _)| !catalogue.iter().any(|p| &p.name == *n)) {
        text += &format!("\"{name}\" = {value:e}\n");
    }
    if !metadata.is_empty() {
        text += "\n";
        text += &toml::to_string(metadata).expect("a TOML table serialises");
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dotted_and_quoted_names_read_the_same() {
        let a = parse_parameters("[parameters]\nelbow.damping = 2\ncommand_delay = 0.012\n").unwrap();
        let b = parse_parameters("[parameters]\n\"elbow.damping\" = 2.0\n\"command_delay\" = 1.2e-2\n[fit]\nnote = 'x'\n").unwrap();
        assert_eq!(a, b);
        assert_eq!(a.get("elbow.damping"), Some(2.0));
        let err = parse_parameters("[parameters]\nelbow.damping = 'high'\n").unwrap_err().to_string();
        assert!(err.contains("'elbow.damping'"), "{err}");
        assert!(parse_parameters("[fit]\n").unwrap_err().to_string().contains("no [parameters]"));
    }
}
