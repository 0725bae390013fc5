//! The options a page or a worker passes in, read into [`Settings`] through the settings table
//! (its ranges and wordings, the same as the CLI's), for both JavaScript APIs: the worker's
//! ([`super::worker_api`]) and the page's ([`super::page_api`]).

use js_sys::Reflect;
use wasm_bindgen::prelude::*;

use crate::settings::{self, Settings, Value};

/// The settings a page may give, checked.
pub(super) struct Options {
    pub settings: Settings,
    pub name: Option<String>,
}

impl Options {
    /// Reads every key of the settings table from `o` (numbers may come as numeric strings,
    /// as form fields give them; a setting that can be off is off at 0, "" or null), plus
    /// `name`, the glTF node's name.
    pub fn from_js(o: &JsValue) -> Result<Options, JsValue> {
        let mut settings = Settings::default();
        let mut name = None;
        if o.is_undefined() || o.is_null() {
            return Ok(Options { settings, name });
        }
        if !o.is_object() {
            return Err(error("TypeError", "options must be an object"));
        }
        for def in settings::TABLE {
            let raw = Reflect::get(o, &JsValue::from_str(def.key))?;
            if raw.is_undefined() {
                continue;
            }
            let value = if raw.is_null() {
                Ok(Value::Off)
            } else if let Some(b) = raw.as_bool() {
                Ok(Value::Bool(b))
            } else if let Some(x) = raw.as_f64() {
                Ok(Value::Num(x))
            } else if let Some(t) = raw.as_string() {
                def.parse(&t)
            } else {
                Err(format!("{} must be {}, not {}", def.key, def.range(), raw.js_typeof().as_string().unwrap_or_default()))
            };
            value.and_then(|v| def.set(&mut settings, v)).map_err(|e| error("RangeError", &e))?;
        }
        if let Some(v) = field(o, "name")? {
            name = Some(v.as_string().ok_or_else(|| error("TypeError", "name must be a string"))?);
        }
        Ok(Options { settings, name })
    }
}

/// `o[key]`, or None when it is undefined or null.
pub(super) fn field(o: &JsValue, key: &str) -> Result<Option<JsValue>, JsValue> {
    let v = Reflect::get(o, &JsValue::from_str(key))?;
    Ok((!v.is_undefined() && !v.is_null()).then_some(v))
}

/// A JS `Error` with `name` set, so callers can tell a cancel ("AbortError") from a failure.
pub(super) fn error(name: &str, message: &str) -> JsValue {
    let e = js_sys::Error::new(message);
    e.set_name(name);
    e.into()
}
