//! The one clock the stages time themselves with: seconds on a monotonic clock since an
//! arbitrary origin. `std::time::Instant` panics on `wasm32-unknown-unknown`, so the browser
//! build reads `performance.now()` (falling back to `Date.now()` where there is no window, as
//! in a Web Worker).

/// Seconds since an arbitrary origin, monotonic.
#[cfg(not(target_arch = "wasm32"))]
pub fn now() -> f64 {
    use std::sync::OnceLock;
    use std::time::Instant;
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_secs_f64()
}

/// Seconds since an arbitrary origin: `performance.now()` where the page has a window,
/// `Date.now()` otherwise.
#[cfg(target_arch = "wasm32")]
pub fn now() -> f64 {
    web_sys::window().and_then(|w| w.performance()).map(|p| p.now()).unwrap_or_else(js_sys::Date::now) / 1e3
}
