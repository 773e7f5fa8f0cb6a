//! Python objects ↔ the language-neutral payload encoding (one MessagePack value; structs as
//! maps keyed by field name, see `docs/wire-format.md`), through `rmpv`.
//!
//! Python → MessagePack: `None` → nil, `bool` → bool, `int` → the smallest int that holds it,
//! `float` → float 64, `str` → str, `bytes`/`bytearray` → bin, `list`/`tuple` → array, `dict` →
//! map (in insertion order), a dataclass instance → map of its fields in declaration order
//! (what a Rust struct with the same fields writes, byte for byte), an `enum.Enum` member → its
//! name (a Rust unit enum variant).
//!
//! MessagePack → Python: nil → `None`, bool, int, float (32 and 64) → `float`, str → `str`,
//! bin → `bytes`, array → `list`, map → `dict` (a key that Python cannot hash, such as an array,
//! becomes a tuple), ext → `(type, bytes)`.

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{
    PyBool, PyByteArray, PyBytes, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple,
};
use rmpv::Value;

use crate::errors;

/// Deepest nesting encoded or decoded (protects against cycles and hostile payloads).
const MAX_DEPTH: usize = 256;

fn encode_error(msg: String) -> PyErr {
    errors::new_err("EncodeError", msg)
}

/// Converts a Python object to a MessagePack value.
pub fn to_value(obj: &Bound<'_, PyAny>) -> PyResult<Value> {
    to_value_at(obj, 0)
}

fn to_value_at(obj: &Bound<'_, PyAny>, depth: usize) -> PyResult<Value> {
    if depth > MAX_DEPTH {
        return Err(encode_error(format!(
            "cannot encode payload: nested deeper than {MAX_DEPTH} levels (a cycle?)"
        )));
    }
    let py = obj.py();
    if obj.is_none() {
        return Ok(Value::Nil);
    }
    if let Ok(b) = obj.cast::<PyBool>() {
        return Ok(Value::Boolean(b.is_true()));
    }
    if obj.cast::<PyInt>().is_ok() {
        if let Ok(i) = obj.extract::<i64>() {
            return Ok(Value::from(i));
        }
        if let Ok(u) = obj.extract::<u64>() {
            return Ok(Value::from(u));
        }
        return Err(encode_error(format!(
            "cannot encode payload: integer {} does not fit in 64 bits",
            obj.str()?
        )));
    }
    if let Ok(f) = obj.cast::<PyFloat>() {
        return Ok(Value::F64(f.value()));
    }
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(Value::from(s.to_cow()?.as_ref()));
    }
    if let Ok(b) = obj.cast::<PyBytes>() {
        return Ok(Value::Binary(b.as_bytes().to_vec()));
    }
    if let Ok(b) = obj.cast::<PyByteArray>() {
        return Ok(Value::Binary(b.to_vec()));
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut entries = Vec::with_capacity(d.len());
        for (k, v) in d.iter() {
            entries.push((to_value_at(&k, depth + 1)?, to_value_at(&v, depth + 1)?));
        }
        return Ok(Value::Map(entries));
    }
    if let Ok(l) = obj.cast::<PyList>() {
        return l
            .iter()
            .map(|v| to_value_at(&v, depth + 1))
            .collect::<PyResult<Vec<_>>>()
            .map(Value::Array);
    }
    if let Ok(t) = obj.cast::<PyTuple>() {
        return t
            .iter()
            .map(|v| to_value_at(&v, depth + 1))
            .collect::<PyResult<Vec<_>>>()
            .map(Value::Array);
    }
    let ty = obj.get_type();
    // A dataclass instance (not the class itself): a map of its fields in declaration order.
    if ty.hasattr("__dataclass_fields__")? {
        let fields = py.import("dataclasses")?.call_method1("fields", (obj,))?;
        let mut entries = Vec::new();
        for field in fields.try_iter()? {
            let name = field?.getattr("name")?;
            let value = obj.getattr(name.cast::<PyString>()?)?;
            entries.push((
                Value::from(name.cast::<PyString>()?.to_cow()?.as_ref()),
                to_value_at(&value, depth + 1)?,
            ));
        }
        return Ok(Value::Map(entries));
    }
    let enum_type = py.import("enum")?.getattr("Enum")?;
    if obj.is_instance(&enum_type)? {
        let name: String = obj.getattr("name")?.extract()?;
        return Ok(Value::from(name));
    }
    Err(encode_error(format!(
        "cannot encode payload: objects of type `{}` have no MessagePack form (use None, bool, int, float, str, bytes, list, tuple, dict, a dataclass or an Enum)",
        ty.qualname()?
    )))
}

/// Converts a MessagePack value to a Python object.
pub fn to_py<'py>(py: Python<'py>, value: &Value) -> PyResult<Bound<'py, PyAny>> {
    to_py_at(py, value, 0)
}

fn to_py_at<'py>(py: Python<'py>, value: &Value, depth: usize) -> PyResult<Bound<'py, PyAny>> {
    if depth > MAX_DEPTH {
        return Err(errors::new_err(
            "DecodeError",
            format!("cannot decode payload: nested deeper than {MAX_DEPTH} levels"),
        ));
    }
    Ok(match value {
        Value::Nil => py.None().into_bound(py),
        Value::Boolean(b) => PyBool::new(py, *b).to_owned().into_any(),
        Value::Integer(i) => match (i.as_i64(), i.as_u64()) {
            (Some(v), _) => v.into_pyobject(py)?.into_any(),
            (None, Some(v)) => v.into_pyobject(py)?.into_any(),
            _ => return Err(PyTypeError::new_err("integer out of range")),
        },
        Value::F32(f) => PyFloat::new(py, f64::from(*f)).into_any(),
        Value::F64(f) => PyFloat::new(py, *f).into_any(),
        Value::String(s) => match s.as_str() {
            Some(s) => PyString::new(py, s).into_any(),
            None => PyBytes::new(py, s.as_bytes()).into_any(),
        },
        Value::Binary(b) => PyBytes::new(py, b).into_any(),
        Value::Array(items) => {
            let list = PyList::empty(py);
            for item in items {
                list.append(to_py_at(py, item, depth + 1)?)?;
            }
            list.into_any()
        }
        Value::Map(entries) => {
            let dict = PyDict::new(py);
            for (k, v) in entries {
                let key = hashable(to_py_at(py, k, depth + 1)?)?;
                dict.set_item(key, to_py_at(py, v, depth + 1)?)?;
            }
            dict.into_any()
        }
        Value::Ext(ty, data) => PyTuple::new(
            py,
            [
                ty.into_pyobject(py)?.into_any(),
                PyBytes::new(py, data).into_any(),
            ],
        )?
        .into_any(),
    })
}

/// Map keys that Python cannot hash (lists, dicts) become tuples (dicts: of (key, value) pairs).
fn hashable(obj: Bound<'_, PyAny>) -> PyResult<Bound<'_, PyAny>> {
    if obj.hash().is_ok() {
        return Ok(obj);
    }
    let py = obj.py();
    if let Ok(l) = obj.cast::<PyList>() {
        let items = l.iter().map(hashable).collect::<PyResult<Vec<_>>>()?;
        return Ok(PyTuple::new(py, items)?.into_any());
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut pairs = Vec::with_capacity(d.len());
        for (k, v) in d.iter() {
            pairs.push(PyTuple::new(py, [k, hashable(v)?])?.into_any());
        }
        return Ok(PyTuple::new(py, pairs)?.into_any());
    }
    Ok(obj)
}

/// Encodes a Python object as one MessagePack value.
pub fn pack(obj: &Bound<'_, PyAny>) -> PyResult<Vec<u8>> {
    let value = to_value(obj)?;
    let mut out = Vec::new();
    rmpv::encode::write_value(&mut out, &value)
        .map_err(|e| encode_error(format!("cannot encode payload: {e}")))?;
    Ok(out)
}

/// Decodes exactly one MessagePack value (trailing bytes are an error, as in Rust).
pub fn unpack_value(bytes: &[u8]) -> Result<Value, String> {
    let mut rd = bytes;
    let value =
        rmpv::decode::read_value(&mut rd).map_err(|e| format!("cannot decode payload: {e}"))?;
    if !rd.is_empty() {
        return Err(format!(
            "cannot decode payload: {} trailing bytes after the value",
            rd.len()
        ));
    }
    Ok(value)
}
