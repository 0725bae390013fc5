//! Small helpers for building JavaScript values.

use js_sys::{Object, Reflect};
use wasm_bindgen::JsValue;

/// `o[key] = value`, ignoring failure (`o` is a fresh plain object).
pub(super) fn set(o: &Object, key: &str, value: impl Into<JsValue>) {
    let _ = Reflect::set(o, &JsValue::from_str(key), &value.into());
}
