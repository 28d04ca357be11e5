//! `--levels NAME=LOW:HIGH,...`: the natural ranges that map coded -1/+1 to physical values.

use anyhow::{anyhow, bail, Result};
use repose_doe::design::Factor;

/// Parses `N2=0.44:0.68,N3=0.01:0.40` into factors, in the given order.
pub fn parse_levels(spec: &str) -> Result<Vec<Factor>> {
    let mut factors = Vec::new();
    for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (name, range) = item
            .split_once('=')
            .ok_or_else(|| anyhow!("--levels: '{item}' is not NAME=LOW:HIGH"))?;
        let (low, high) = range
            .split_once(':')
            .ok_or_else(|| anyhow!("--levels: '{item}' is not NAME=LOW:HIGH"))?;
        let parse = |s: &str, what: &str| -> Result<f64> {
            s.trim().parse::<f64>().map_err(|_| {
                anyhow!(
                    "--levels: {what} of '{}' is not a number: '{s}'",
                    name.trim()
                )
            })
        };
        let factor = Factor::new(name.trim(), parse(low, "low")?, parse(high, "high")?)
            .map_err(|e| anyhow!("--levels: {e}"))?;
        if factors.iter().any(|f: &Factor| f.name == factor.name) {
            bail!("--levels: factor '{}' is given twice", factor.name);
        }
        factors.push(factor);
    }
    if factors.is_empty() {
        bail!("--levels: no factor given");
    }
    Ok(factors)
}

/// The factor ranges for `names`, in that order, from parsed `--levels`.
pub fn levels_for(names: &[String], levels: &[Factor]) -> Result<Vec<Factor>> {
    names
        .iter()
        .map(|n| {
            levels
                .iter()
                .find(|f| &f.name == n)
                .cloned()
                .ok_or_else(|| anyhow!("--levels: no range given for factor '{n}'"))
        })
        .collect()
}
