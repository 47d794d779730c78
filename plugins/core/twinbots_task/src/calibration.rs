//! Calibration and truth files: TOML with a `[parameters]` table of `name = value` (SI units,
//! the names `twinbots identify <robot> --list-params` prints) and any other tables of
//! metadata. A name holds dots (`elbow_joint.damping`); written bare, TOML reads it as a dotted
//! key (a nested table), quoted as one key: both read the same. `twinbots identify` adds a
//! `[spread]` table (each fitted value's standard deviation, same names and units), which domain
//! randomization can draw around the fit with (`randomization.calibration_spread`).

use std::path::Path;

use anyhow::{Context, bail};
use twinbots_sim::{ParameterSpec, Parameters};

/// Reads the `[parameters]` of a calibration's TOML text; the error names the entry at fault.
pub fn parse_parameters(text: &str) -> anyhow::Result<Parameters> {
    parameters_of(&toml_table(text)?)
}

/// Reads the `[spread]` of a calibration's TOML text (none: an empty set).
pub fn parse_spread(text: &str) -> anyhow::Result<Parameters> {
    spread_of(&toml_table(text)?)
}

fn toml_table(text: &str) -> anyhow::Result<toml::Table> {
    toml::from_str(text).map_err(|e| anyhow::anyhow!("not valid TOML: {e}"))
}

fn parameters_of(table: &toml::Table) -> anyhow::Result<Parameters> {
    values_of(table, "parameters")?.ok_or_else(|| anyhow::anyhow!("no [parameters] table"))
}

fn spread_of(table: &toml::Table) -> anyhow::Result<Parameters> {
    Ok(values_of(table, "spread")?.unwrap_or_default())
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

/// Reads a calibration (or truth) file and checks its names against the robot's parameters;
/// errors name the file.
pub fn read_calibration(path: &Path, catalogue: &[ParameterSpec], robot: &str) -> anyhow::Result<Parameters> {
    Ok(read_calibration_with_spread(path, catalogue, robot)?.0)
}

/// [`read_calibration`] and the file's `[spread]`: every name a parameter the file sets, every
/// value finite and ≥ 0.
pub fn read_calibration_with_spread(
    path: &Path,
    catalogue: &[ParameterSpec],
    robot: &str,
) -> anyhow::Result<(Parameters, Parameters)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read calibration {}", path.display()))?;
    let in_file = || format!("calibration {}", path.display());
    let table = toml_table(&text).with_context(in_file)?;
    let params = parameters_of(&table).with_context(in_file)?;
    params.check(catalogue, robot).map_err(|e| anyhow::anyhow!("{}: {e}", in_file()))?;
    let spread = spread_of(&table).with_context(in_file)?;
    for (name, sigma) in &spread.0 {
        anyhow::ensure!(
            params.0.contains_key(name),
            "calibration {}: [spread] names '{name}', which its [parameters] do not set",
            path.display()
        );
        anyhow::ensure!(
            sigma.is_finite() && *sigma >= 0.0,
            "calibration {}: [spread] '{name}' = {sigma}: must be finite and ≥ 0",
            path.display()
        );
    }
    Ok((params, spread))
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
        let b =
            parse_parameters("[parameters]\n\"elbow.damping\" = 2.0\n\"command_delay\" = 1.2e-2\n[fit]\nnote = 'x'\n")
                .unwrap();
        assert_eq!(a, b);
        assert_eq!(a.get("elbow.damping"), Some(2.0));
        let err = parse_parameters("[parameters]\nelbow.damping = 'high'\n").unwrap_err().to_string();
        assert!(err.contains("'elbow.damping'"), "{err}");
        assert!(parse_parameters("[fit]\n").unwrap_err().to_string().contains("no [parameters]"));
        assert_eq!(parse_spread("[parameters]\nx = 1\n").unwrap(), Parameters::default());
        assert_eq!(parse_spread("[spread]\n\"elbow.damping\" = 0.5\n").unwrap().get("elbow.damping"), Some(0.5));
    }
}
