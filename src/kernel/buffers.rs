//! Large `f32` buffers, reused: a fresh multi-megabyte allocation is a fresh `mmap`
//! whose every page the kernel zeroes on first touch, which cost the multi-scale network
//! a fifth of its time on large tiles. Freed planes go back to a pool, and new ones are
//! asked to use transparent huge pages.

use std::alloc::GlobalAlloc;
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
    advise_huge_range(v.as_mut_ptr().cast(), v.capacity() * 4);
}

/// [`advise_huge`] on `bytes` bytes at `start`: the huge pages that fit inside the block.
fn advise_huge_range(start: *mut u8, bytes: usize) {
    const HUGE_PAGE: usize = 2 << 20;
    #[cfg(target_os = "linux")]
    if bytes >= HUGE_PAGE && !start.is_null() {
        let start = start as usize;
        let (from, to) = (start.next_multiple_of(HUGE_PAGE), (start + bytes) / HUGE_PAGE * HUGE_PAGE);
        if to > from {
            // SAFETY: the range lies inside this allocation; MADV_HUGEPAGE only changes
            // how the kernel backs it, never its contents. Failure is harmless.
            unsafe { libc::madvise(from as *mut libc::c_void, to - from, libc::MADV_HUGEPAGE) };
        }
    }
}

/// The system allocator, with every block of 2 MiB and more backed by transparent huge
/// pages where they fit inside it (`MADV_HUGEPAGE`): a 1280×720 file's decoded channels,
/// mapped inputs, features and network inputs (3.7 MB a plane) are ~1 GB of fresh memory,
/// whose first touch cost 295,000 page faults; 198,000 with this (the rest are OpenImageIO's
/// and OpenEXR's), and the command 7 % faster (BENCHMARKS.md). For processes that own their
/// allocator (the CLI: `#[global_allocator]`), never the library on a host's behalf.
pub struct HugePageAllocator;

// SAFETY: every call is forwarded to `System` unchanged; the advice only changes how the
// kernel backs the returned memory, never its contents or ownership.
unsafe impl GlobalAlloc for HugePageAllocator {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { std::alloc::System.alloc(layout) };
        advise_huge_range(p, layout.size());
        p
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { std::alloc::System.alloc_zeroed(layout) };
        advise_huge_range(p, layout.size());
        p
    }

    unsafe fn dealloc(&self, p: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { std::alloc::System.dealloc(p, layout) }
    }

    unsafe fn realloc(&self, p: *mut u8, layout: std::alloc::Layout, size: usize) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let q = unsafe { std::alloc::System.realloc(p, layout, size) };
        advise_huge_range(q, size);
        q
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
/// 1.0 GB with this. Every thread also shares the main heap: the network streamed down a
/// frame allocates each step's rows on both of its threads, and per-thread heaps kept
/// about 90 MB more of them at 4K (1.02 GB against 0.94). For processes that stream
/// frames, the CLI's `denoise`; call it before other threads start.
pub fn return_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes glibc's allocation policy; a refused value is harmless.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 8 << 20);
        libc::mallopt(libc::M_ARENA_MAX, 1);
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

    /// Kilobytes of huge pages backing the mapping that holds `addr` (`/proc/self/smaps`).
    #[cfg(target_os = "linux")]
    fn huge_kb_at(addr: usize) -> Option<usize> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
        let mut inside = false;
        for line in smaps.lines() {
            // A mapping's first line starts `start-end` in hex; its fields follow.
            let range = line
                .split_whitespace()
                .next()
                .and_then(|r| r.split_once('-'))
                .and_then(|(a, b)| Some((usize::from_str_radix(a, 16).ok()?, usize::from_str_radix(b, 16).ok()?)));
            if let Some((a, b)) = range {
                inside = (a..b).contains(&addr);
                continue;
            }
            if inside && let Some(kb) = line.strip_prefix("AnonHugePages:") {
                return kb.trim().trim_end_matches("kB").trim().parse().ok();
            }
        }
        None
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn the_allocator_backs_large_blocks_with_huge_pages() {
        use std::alloc::{GlobalAlloc, Layout};
        let thp = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").unwrap_or_default();
        let layout = Layout::from_size_align(32 << 20, 64).unwrap();
        // SAFETY: a non-zero layout; the block is written within its size and freed once.
        unsafe {
            let p = HugePageAllocator.alloc_zeroed(layout);
            assert!(!p.is_null());
            std::ptr::write_bytes(p, 1, layout.size());
            let q = HugePageAllocator.realloc(p, layout, 48 << 20);
            assert!(!q.is_null() && *q.add(layout.size() - 1) == 1, "realloc keeps the contents");
            std::ptr::write_bytes(q.add(layout.size()), 2, 16 << 20);
            let huge = [8, 40].map(|mb| huge_kb_at(q as usize + (mb << 20)));
            HugePageAllocator.dealloc(q, Layout::from_size_align(48 << 20, 64).unwrap());
            // Only where the kernel offers huge pages on request (`[madvise]` or `[always]`).
            if thp.contains("[madvise]") || thp.contains("[always]") {
                assert!(huge.iter().all(|h| h.is_some_and(|kb| kb >= 2048)), "huge pages: {huge:?} kB ({thp})");
            }
        }
    }

    fn zeroed_from(mut v: Vec<f32>, n: usize) -> Vec<f32> {
        v.resize(n, 0.0);
        v
    }
}
