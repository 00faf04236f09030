//! A run configuration from Python: a dict (converted to TOML, the one configuration language,
//! and parsed by the same code as a file), a TOML string, or a path.

use std::path::{Path, PathBuf};

use chaoscope_schemas::config::{RunConfig, parse_config_bytes, read_config_file};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

/// The configuration `obj` describes.
pub fn run_config(obj: &Bound<'_, PyAny>) -> PyResult<RunConfig> {
    if let Ok(dict) = obj.cast::<PyDict>() {
        let table = table(dict, "")?;
        let text = toml::to_string(&table).map_err(|e| crate::message(format!("config: {e}")))?;
        return parse_config_bytes("config", text.into_bytes(), Path::new(""))
            .map_err(|e| crate::error(&e));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        let s: String = s.extract()?;
        // Every TOML configuration assigns a key; a path of a configuration file hardly does.
        if s.contains('=') || s.contains('\n') {
            return parse_config_bytes("config", s.as_bytes().to_vec(), Path::new(""))
                .map_err(|e| crate::error(&e));
        }
        return read_config_file(Path::new(&s)).map_err(|e| crate::error(&e));
    }
    match obj.extract::<PathBuf>() {
        Ok(path) => read_config_file(&path).map_err(|e| crate::error(&e)),
        Err(_) => Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "config: expected a dict, a TOML string or a path, got {}",
            obj.get_type().name()?
        ))),
    }
}

/// The file `obj` names, when the configuration is given as a path (which an output must then
/// not be).
pub fn config_path(obj: &Bound<'_, PyAny>) -> Option<PathBuf> {
    if obj.cast::<PyDict>().is_ok() {
        return None;
    }
    if let Ok(s) = obj.cast::<PyString>() {
        let s: String = s.extract().ok()?;
        return (!(s.contains('=') || s.contains('\n'))).then(|| PathBuf::from(s));
    }
    obj.extract::<PathBuf>().ok()
}

fn key_path(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

fn table(dict: &Bound<'_, PyDict>, prefix: &str) -> PyResult<toml::Table> {
    let mut out = toml::Table::new();
    for (k, v) in dict.iter() {
        let key: String = k.extract().map_err(|_| {
            crate::message(format!("config: {prefix}: keys must be strings, got {k}"))
        })?;
        let path = key_path(prefix, &key);
        if v.is_none() {
            // TOML has no null: an absent key is how a default is asked for.
            continue;
        }
        out.insert(key, value(&v, &path)?);
    }
    Ok(out)
}

fn value(v: &Bound<'_, PyAny>, path: &str) -> PyResult<toml::Value> {
    if v.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(v.extract()?));
    }
    if v.is_instance_of::<PyInt>() {
        return match v.extract::<i64>() {
            Ok(i) => Ok(toml::Value::Integer(i)),
            Err(_) => Err(crate::message(format!(
                "config: {path}: integer {v} does not fit in 64 bits"
            ))),
        };
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(v.extract()?));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(toml::Value::String(s.extract()?));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        return Ok(toml::Value::Table(table(d, path)?));
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        let items: Vec<Bound<'_, PyAny>> = v.try_iter()?.collect::<PyResult<_>>()?;
        return items
            .iter()
            .enumerate()
            .map(|(i, item)| value(item, &format!("{path}[{i}]")))
            .collect::<PyResult<Vec<_>>>()
            .map(toml::Value::Array);
    }
    // numpy arrays and scalars: their plain Python form.
    if v.hasattr("tolist")? {
        let plain = v.call_method0("tolist")?;
        if !plain.is(v) {
            return value(&plain, path);
        }
    }
    Err(crate::message(format!(
        "config: {path}: a {} has no TOML form (use numbers, strings, booleans, lists, dicts)",
        v.get_type().name()?
    )))
}
