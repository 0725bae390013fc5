//! Loops over independent items (a neighbour search per point or per vertex), split over the
//! cores: natively on scoped threads; on `wasm32` on the page's pool of Web Workers where the
//! threaded build runs (feature `wasm-threads`, a cross-origin isolated page), else on the
//! calling thread.
//!
//! Why: on a real GPU the network's part of a scene is a few percent of its time; the rest is
//! such loops on one core (docs/scenes.md, "On a GPU"). Each item is computed alone and the
//! results are concatenated in order, so they are the same bits for any number of threads
//! ([`threads`]: `NKRR_THREADS`, else every core). `krr::linalg`'s kernels take the same count.

use std::ops::Range;

/// Threads a loop may use: `NKRR_THREADS` if set to a positive integer, else
/// `available_parallelism()` (natively); always 1 on `wasm32`.
#[cfg(not(target_arch = "wasm32"))]
pub(crate) fn threads() -> usize {
    use std::sync::OnceLock;
    static N: OnceLock<usize> = OnceLock::new();
    *N.get_or_init(|| {
        std::env::var("NKRR_THREADS")
            .ok()
            .and_then(|v| v.trim().parse::<usize>().ok())
            .filter(|&n| n > 0)
            .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
    })
}

/// Threads a loop may use on `wasm32`: the page's pool once it is up ([`set_pool_threads`]), 1
/// before and in the plain build. Until the pool is up nothing may call into rayon: its global
/// pool would try to start threads of its own, which the browser cannot.
#[cfg(target_arch = "wasm32")]
pub(crate) fn threads() -> usize {
    #[cfg(feature = "wasm-threads")]
    return POOL_THREADS.load(std::sync::atomic::Ordering::Relaxed);
    #[cfg(not(feature = "wasm-threads"))]
    1
}

#[cfg(all(target_arch = "wasm32", feature = "wasm-threads"))]
static POOL_THREADS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(1);

/// Called once wasm-bindgen-rayon's pool of `n` workers is up (`web/worker.js` awaits
/// `initThreadPool(n)` first): from then on the loops and `krr::linalg` split over them.
#[cfg(all(target_arch = "wasm32", feature = "wasm-threads"))]
pub(crate) fn set_pool_threads(n: usize) {
    POOL_THREADS.store(n.max(1), std::sync::atomic::Ordering::Relaxed);
}

/// Fewest items worth a thread of its own: an item is a neighbour search or less (a few µs),
/// starting a thread tens of µs.
const MIN_ITEMS_PER_THREAD: usize = 2048;

/// Threads for `n` items: [`threads`], fewer when there are not enough items for them.
fn threads_for(n: usize) -> usize {
    threads().min(n / MIN_ITEMS_PER_THREAD).max(1)
}

/// `f(range)` over consecutive ranges that cover `0..n`, their outputs concatenated in order.
/// `f` makes its own scratch space, once per range.
pub fn map_ranges<R: Send>(n: usize, f: impl Fn(Range<usize>) -> Vec<R> + Sync) -> Vec<R> {
    let chunk = n.div_ceil(threads_for(n)).max(1);
    let ranges: Vec<Range<usize>> = (0..n).step_by(chunk).map(|a| a..(a + chunk).min(n)).collect();
    if ranges.len() <= 1 {
        return f(0..n);
    }
    run(ranges, &f).into_iter().flatten().collect()
}

/// Fills `out` chunk by chunk, the chunks split over the cores: `f(start, chunk)` fills
/// `out[start..start + chunk.len()]` (with scratch space of its own) and returns a summary of
/// it (a count, say); the summaries come back in order. Writes in place: no second copy of a
/// large output, as [`map_ranges`]'s concatenation would make.
pub fn fill<R: Send, S: Send>(out: &mut [R], f: impl Fn(usize, &mut [R]) -> S + Sync) -> Vec<S> {
    let chunk = out.len().div_ceil(threads_for(out.len())).max(1);
    if chunk >= out.len() {
        return vec![f(0, out)];
    }
    let parts: Vec<(usize, &mut [R])> = out.chunks_mut(chunk).enumerate().map(|(c, part)| (c * chunk, part)).collect();
    run(parts, &|(start, part)| f(start, part))
}

/// `f` of each part on a scoped thread of its own, the results in the parts' order (natively;
/// on `wasm32`, on the page's pool or, in the plain build, where [`threads`] is 1 and nothing
/// gets here, one after the other).
#[cfg(not(target_arch = "wasm32"))]
fn run<P: Send, S: Send>(parts: Vec<P>, f: &(impl Fn(P) -> S + Sync)) -> Vec<S> {
    std::thread::scope(|s| {
        let handles: Vec<_> = parts.into_iter().map(|part| s.spawn(move || f(part))).collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    })
}

/// On the page's pool: an indexed parallel iterator keeps the parts' order.
#[cfg(all(target_arch = "wasm32", feature = "wasm-threads"))]
fn run<P: Send, S: Send>(parts: Vec<P>, f: &(impl Fn(P) -> S + Sync)) -> Vec<S> {
    use rayon::prelude::*;
    parts.into_par_iter().map(f).collect()
}

#[cfg(all(target_arch = "wasm32", not(feature = "wasm-threads")))]
fn run<P: Send, S: Send>(parts: Vec<P>, f: &(impl Fn(P) -> S + Sync)) -> Vec<S> {
    parts.into_iter().map(f).collect()
}

/// `items.iter().map(f)`, split as [`map_ranges`] splits.
pub fn map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    map_ranges(items.len(), |r| items[r].iter().map(&f).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_cover_every_item_once_in_order() {
        for n in [0, 1, 2047, 2048, 4096, 10_001, 100_000] {
            let got = map_ranges(n, |r| r.map(|i| i * 3).collect());
            assert_eq!(got, (0..n).map(|i| i * 3).collect::<Vec<_>>(), "n={n}");
        }
        let items: Vec<u32> = (0..50_000).collect();
        assert_eq!(map(&items, |&x| x + 1), (1..50_001).collect::<Vec<u32>>());
    }

    #[test]
    fn fill_writes_every_item_in_place_and_returns_the_chunks_summaries_in_order() {
        for n in [0, 1, 5000, 100_001] {
            let mut out = vec![u64::MAX; n];
            let counts = fill(&mut out, |start, chunk| {
                for (j, x) in chunk.iter_mut().enumerate() {
                    *x = ((start + j) * 7) as u64;
                }
                chunk.len()
            });
            assert_eq!(out, (0..n).map(|i| (i * 7) as u64).collect::<Vec<_>>(), "n={n}");
            assert_eq!(counts.iter().sum::<usize>(), n);
        }
    }

    #[test]
    #[should_panic(expected = "item 9000")]
    fn a_panic_in_a_worker_reaches_the_caller() {
        map_ranges(20_000, |r| {
            assert!(!r.contains(&9000), "item 9000");
            r.collect::<Vec<_>>()
        });
    }
}
