//! Large `f32` buffers, reused: a fresh multi-megabyte allocation is a fresh `mmap`
//! whose every page the kernel zeroes on first touch, which cost the multi-scale network
//! a fifth of its time on large tiles. Freed planes go back to a pool, and new ones are
//! asked to use transparent huge pages.

use std::sync::Mutex;

/// Buffers smaller than this many floats (1 MiB) are left to the allocator.
const MIN: usize = 1 << 18;
/// The pool keeps at least this many floats (64 MiB) of idle buffers; a [`Lease`] raises it.
const KEEP: usize = 16 << 20;

/// Idle buffers, oldest first, and the floats leased beyond [`KEEP`].
static POOL: Mutex<Pool> = Mutex::new(Pool { idle: Vec::new(), leased: 0 });

struct Pool {
    idle: Vec<Vec<f32>>,
    leased: usize,
}

impl Pool {
    /// Frees the oldest idle buffers beyond the bound.
    fn trim(&mut self) {
        let keep = KEEP + self.leased;
        while self.idle.iter().map(Vec::capacity).sum::<usize>() > keep {
            self.idle.remove(0);
        }
    }
}

fn pool() -> std::sync::MutexGuard<'static, Pool> {
    POOL.lock().unwrap_or_else(|e| e.into_inner())
}

/// While alive, lets the pool keep `bytes` more of idle buffers: a tile's network
/// activations (the 720p default's are 120 MB a layer) are then reused from layer to layer
/// and tile to tile instead of being zeroed anew by the kernel, which took an eighth of a
/// 720p file's time. The memory is counted in the working budget that leased it, and is
/// freed when the lease ends.
pub struct Lease(usize);

impl Lease {
    /// Raises the pool's bound by `bytes` until dropped.
    pub fn new(bytes: usize) -> Lease {
        let floats = bytes / 4;
        pool().leased += floats;
        Lease(floats)
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        let mut pool = pool();
        pool.leased -= self.0;
        pool.trim();
    }
}

/// Whether `bytes` can be allocated now, by asking the allocator once and giving them back:
/// under an address-space limit (`ulimit -v`, a farm's cgroup) work that would run out
/// half-way, which Rust answers with an abort, is refused before it starts.
pub fn can_allocate(bytes: usize) -> bool {
    let mut probe: Vec<u8> = Vec::new();
    probe.try_reserve_exact(bytes).is_ok()
}

/// An empty buffer with room for `n` values: a pooled one when one fits (at most twice the
/// room needed), else a new one backed by huge pages where the kernel allows it.
pub fn with_capacity(n: usize) -> Vec<f32> {
    if n >= MIN {
        let pool = &mut pool().idle;
        let best = (0..pool.len()).filter(|&i| pool[i].capacity() >= n).min_by_key(|&i| pool[i].capacity());
        if let Some(i) = best {
            let mut v = pool.swap_remove(i);
            v.clear();
            return v;
        }
    }
    let mut v = Vec::with_capacity(n);
    advise_huge(&mut v);
    v
}

/// `n` zeros, from [`with_capacity`].
pub fn zeroed(n: usize) -> Vec<f32> {
    let mut v = with_capacity(n);
    v.resize(n, 0.0);
    v
}

/// Gives a buffer back for reuse (small ones are simply freed); the oldest idle buffers
/// are freed beyond the pool's bound.
pub fn recycle(v: Vec<f32>) {
    if v.capacity() < MIN {
        return;
    }
    let mut pool = pool();
    pool.idle.push(v);
    pool.trim();
}

/// Asks the kernel to back a large buffer with transparent huge pages: 512 times fewer
/// page faults on first touch.
fn advise_huge(v: &mut Vec<f32>) {
    const HUGE_PAGE: usize = 2 << 20;
    let bytes = v.capacity() * 4;
    #[cfg(target_os = "linux")]
    if bytes >= 2 * HUGE_PAGE {
        let start = v.as_mut_ptr() as usize;
        let (from, to) = (start.next_multiple_of(HUGE_PAGE), (start + bytes) / HUGE_PAGE * HUGE_PAGE);
        if to > from {
            // SAFETY: the range lies inside this allocation; MADV_HUGEPAGE only changes
            // how the kernel backs it, never its contents. Failure is harmless.
            unsafe { libc::madvise(from as *mut libc::c_void, to - from, libc::MADV_HUGEPAGE) };
        }
    }
}

/// Makes the C allocator keep freed memory for reuse instead of returning it to the
/// kernel: blocks up to 32 MiB come from the heap, not from a fresh `mmap`; every thread
/// uses the main heap (glibc shrinks the per-thread ones with `MADV_DONTNEED`); and the
/// heap is never trimmed. Training allocates and frees the same tensor sizes every step,
/// and without this each of them page-faults anew (measured: a 1×1 layer's backward
/// pass on a training batch, 14 ms → 5.6 ms). Call it before other threads start. The
/// process keeps its peak footprint, so this is for processes that own their allocator,
/// the CLI's trainer and benchmarks, never the library on a host's behalf.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation policy; a refused value is harmless.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_ARENA_MAX, 1);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// Makes the C allocator return blocks of 8 MiB and up to the kernel as soon as they are
/// freed (a fixed `mmap` threshold). By default glibc raises the threshold to the size of
/// each such block freed, up to 32 MiB, and from then on serves them from its heap, where
/// a streamed frame's band planes (a 4K band's: 12 MB each) and tile buffers of varying
/// sizes fragment it: a 4K file through the `balanced` network peaked at 1.45 GB, and at
/// 1.0 GB with this. For processes that stream frames, the CLI's `denoise`; call it before
/// other threads start.
pub fn return_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation policy; a refused value is harmless.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 8 << 20);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recycled_buffer_is_reused_and_comes_back_empty() {
        let mut v = zeroed(MIN * 3 + 5);
        v[7] = 1.0;
        let ptr = v.as_ptr();
        recycle(v);
        let w = with_capacity(MIN * 3);
        assert!(w.is_empty() && w.capacity() >= MIN * 3);
        // Another test may have taken it first; when it is ours, it is the same memory.
        if w.as_ptr() == ptr {
            assert_eq!(zeroed_from(w, MIN * 3)[7], 0.0);
        }
    }

    fn zeroed_from(mut v: Vec<f32>, n: usize) -> Vec<f32> {
        v.resize(n, 0.0);
        v
    }
}
