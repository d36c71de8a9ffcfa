//! `--set KEY=VALUE` overrides: parsing the argument, and setting or removing a dotted key in
//! the configuration's TOML table.

/// Parses a `--set KEY=VALUE` argument: a dotted key and a TOML value. A value that is not
/// valid TOML is taken as a string, so `--set gps.mode=fake-zero` works without quotes.
pub fn parse_set(arg: &str) -> Result<(String, toml::Value), String> {
    let (key, value) = arg
        .split_once('=')
        .ok_or_else(|| format!("--set {arg:?}: expected KEY=VALUE"))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(|p| p.trim().is_empty()) {
        return Err(format!(
            "--set {arg:?}: the key must be dotted names like vehicle.mass_kg"
        ));
    }
    let value = value.trim();
    let parsed = toml::from_str::<toml::Table>(&format!("v = {value}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.to_string()));
    Ok((key.to_string(), parsed))
}

/// Sets `key` (dotted) to `value`, creating the tables on the way; fails when a part of the
/// way is a value rather than a table.
pub(super) fn set_dotted(
    table: &mut toml::Table,
    key: &str,
    value: toml::Value,
) -> Result<(), String> {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            cur.insert((*part).to_string(), value);
            return Ok(());
        }
        let entry = cur
            .entry((*part).to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = entry
            .as_table_mut()
            .ok_or_else(|| format!("{} is not a table", parts[..=i].join(".")))?;
    }
    Ok(())
}

/// Removes `key` (dotted); false when it is not there.
pub(super) fn remove_dotted(table: &mut toml::Table, key: &str) -> bool {
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, part) in parts.iter().enumerate() {
        if i + 1 == parts.len() {
            return cur.remove(*part).is_some();
        }
        match cur.get_mut(*part).and_then(|v| v.as_table_mut()) {
            Some(t) => cur = t,
            None => return false,
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn set_values_parse_as_toml_or_string() {
        assert_eq!(
            parse_set("vehicle.mass_kg=-3").unwrap(),
            ("vehicle.mass_kg".into(), toml::Value::Integer(-3))
        );
        assert_eq!(
            parse_set("gps.mode=fake-zero").unwrap().1,
            toml::Value::String("fake-zero".into())
        );
        assert_eq!(
            parse_set("gps.mode=\"off\"").unwrap().1,
            toml::Value::String("off".into())
        );
        assert!(parse_set("novalue").is_err());
        assert!(parse_set("a..b=1").is_err());
    }
}
