//! C++'s `operator new` and `operator delete` for wasm32, where there is no C++ runtime:
//! meshoptimizer (the `meshopt` crate, built by clang with its libc-free headers) allocates its
//! scratch memory through them. They go to Rust's allocator, with the size kept in a header
//! before the block because `operator delete(void*)` is not told it.

use std::alloc::{alloc, dealloc, Layout};

/// Header bytes before each block: the size, padded so the block keeps `max_align_t`'s
/// alignment (16 on wasm32).
const HEADER: usize = 16;

fn layout(size: usize) -> Option<Layout> {
    Layout::from_size_align(size.checked_add(HEADER)?, HEADER).ok()
}

/// `operator new(size_t)` and `operator new[](size_t)`. meshoptimizer checks for no result, so
/// a failure returns null rather than throwing (there are no exceptions here).
unsafe fn new(size: usize) -> *mut u8 {
    let Some(l) = layout(size) else { return std::ptr::null_mut() };
    // SAFETY: the layout's size is at least HEADER > 0.
    let p = unsafe { alloc(l) };
    if p.is_null() {
        return p;
    }
    // SAFETY: p is a fresh block of size + HEADER bytes, aligned to HEADER.
    unsafe {
        (p as *mut usize).write(size);
        p.add(HEADER)
    }
}

/// `operator delete(void*)` and `operator delete[](void*)`: frees a block from [`new`].
unsafe fn delete(p: *mut u8) {
    if p.is_null() {
        return;
    }
    // SAFETY: p came from `new`, so the header (with the size) is HEADER bytes before it.
    unsafe {
        let base = p.sub(HEADER);
        let size = (base as *const usize).read();
        dealloc(base, layout(size).expect("the layout was valid when allocated"));
    }
}

#[unsafe(no_mangle)]
unsafe extern "C" fn _Znwm(size: usize) -> *mut u8 {
    unsafe { new(size) }
}

#[unsafe(no_mangle)]
unsafe extern "C" fn _Znam(size: usize) -> *mut u8 {
    unsafe { new(size) }
}

#[unsafe(no_mangle)]
unsafe extern "C" fn _ZdlPv(p: *mut u8) {
    unsafe { delete(p) }
}

#[unsafe(no_mangle)]
unsafe extern "C" fn _ZdaPv(p: *mut u8) {
    unsafe { delete(p) }
}
