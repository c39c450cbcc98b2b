//! Reading lossless EXRs with OpenEXRCore, OpenImageIO's newer EXR reader, for processes
//! that own their allocator (the CLI's `denoise`), never the library on a host's behalf.
//!
//! The classic reader converts every decoded sample from the file's byte order one byte
//! at a time in a call of its own (`Xdr::read`): a tenth of a 4K file command's cycles,
//! the file being decoded about three times (the statistics pass, the bands, the copied
//! channels). OpenEXRCore copies samples of the file's own type whole. It allocates its
//! chunk buffers afresh for every chunk, though (a 3840-wide chunk of 41 float channels:
//! 10 MB decompressed, as much again of scratch), which glibc maps and the kernel zeroes
//! anew each time; so the process's OpenEXRCore allocations go through [`alloc`] and
//! [`free`], which keep up to [`KEEP`] bytes of freed large blocks for the next chunk.
//!
//! Only scanline files of a lossless compression are read so ([`qualifies`]): Debian's
//! OpenImageIO 2.4 reports a valid DWAA file as corrupt through OpenEXRCore.

use super::LOSSLESS_COMPRESSIONS;
use std::collections::VecDeque;
use std::ffi::c_void;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

/// Whether [`read_lossless_exr_with_openexr_core`] was called.
static ENABLED: AtomicBool = AtomicBool::new(false);

/// Has lossless scanline EXRs read with OpenEXRCore from now on, its chunk buffers reused
/// (freed ones kept, up to a bound). Process-wide: for the CLI, before any file is
/// opened. Where OpenImageIO's OpenEXRCore is not there to be found, files are read as
/// before.
pub fn read_lossless_exr_with_openexr_core() {
    #[cfg(target_os = "linux")]
    {
        type Alloc = extern "C" fn(usize) -> *mut c_void;
        type Free = extern "C" fn(*mut c_void);
        // SAFETY: looks a symbol up in the libraries already loaded (OpenImageIO's
        // OpenEXRCore); a null result is checked.
        let f = unsafe { libc::dlsym(libc::RTLD_DEFAULT, c"exr_set_default_memory_routines".as_ptr()) };
        if f.is_null() {
            return;
        }
        // SAFETY: OpenEXR 3's `void exr_set_default_memory_routines(exr_memory_allocation_func_t,
        // exr_memory_free_func_t)`, whose two types are `void* (*)(size_t)` and `void (*)(void*)`.
        let set: extern "C" fn(Alloc, Free) = unsafe { std::mem::transmute(f) };
        set(alloc, free);
        ENABLED.store(true, Ordering::Relaxed);
    }
}

/// Whether [`read_lossless_exr_with_openexr_core`] was called (and found OpenEXRCore).
pub(crate) fn enabled() -> bool {
    ENABLED.load(Ordering::Relaxed)
}

/// Whether a file of this format, compression and tiling is read with OpenEXRCore once
/// [`enabled`].
pub(crate) fn qualifies(format: &str, compression: Option<&str>, tiled: bool) -> bool {
    let name = compression.unwrap_or("").split(':').next().unwrap_or("");
    format == "openexr" && !tiled && LOSSLESS_COMPRESSIONS.contains(&name)
}

/// Bytes before each block [`alloc`] hands out: its size, and malloc's alignment kept.
const HEADER: usize = 64;
/// Blocks from this size up are rounded up to a multiple of it and kept when freed.
const LARGE: usize = 1 << 20;
/// The most bytes of freed blocks kept: two decoders' chunks, compressed and not, with
/// scratch, at 3840 × 41 float channels; the oldest go first.
const KEEP: usize = 64 << 20;

/// Freed large blocks (address of the header, size), oldest first.
static IDLE: Mutex<VecDeque<(usize, usize)>> = Mutex::new(VecDeque::new());

fn idle() -> std::sync::MutexGuard<'static, VecDeque<(usize, usize)>> {
    IDLE.lock().unwrap_or_else(|e| e.into_inner())
}

/// OpenEXRCore's allocation: a kept block that fits (at most a quarter larger than asked:
/// a compressed chunk must not take a decompressed chunk's block), else
/// `malloc`. Null when memory runs out, which OpenEXRCore reports as an error.
extern "C" fn alloc(bytes: usize) -> *mut c_void {
    let size = if bytes >= LARGE { bytes.next_multiple_of(LARGE) } else { bytes };
    if size >= LARGE {
        let mut idle = idle();
        let best =
            (0..idle.len()).filter(|&i| idle[i].1 >= size && idle[i].1 <= size + size / 4).min_by_key(|&i| idle[i].1);
        if let Some((block, _)) = best.and_then(|i| idle.remove(i)) {
            // SAFETY: a block of at least HEADER + size bytes from below, not in use.
            return unsafe { (block as *mut u8).add(HEADER) }.cast();
        }
    }
    let Some(total) = size.checked_add(HEADER) else { return std::ptr::null_mut() };
    // SAFETY: plain malloc; the result is checked.
    let block = unsafe { libc::malloc(total) }.cast::<u8>();
    if block.is_null() {
        return block.cast();
    }
    // SAFETY: the block holds HEADER bytes and more, aligned for a usize by malloc.
    unsafe {
        block.cast::<usize>().write(size);
        block.add(HEADER).cast()
    }
}

/// OpenEXRCore's free, of a block from [`alloc`]: a large one is kept for reuse, the
/// oldest kept ones freed beyond [`KEEP`].
extern "C" fn free(p: *mut c_void) {
    if p.is_null() {
        return;
    }
    // SAFETY: `p` came from `alloc`, HEADER bytes into a block whose size it wrote there.
    let (block, size) = unsafe {
        let block = p.cast::<u8>().sub(HEADER);
        (block, block.cast::<usize>().read())
    };
    if size < LARGE {
        // SAFETY: the block came from malloc and is freed once.
        unsafe { libc::free(block.cast()) };
        return;
    }
    let mut idle = idle();
    idle.push_back((block as usize, size));
    let mut kept: usize = idle.iter().map(|b| b.1).sum();
    while kept > KEEP {
        let Some((old, bytes)) = idle.pop_front() else { break };
        kept -= bytes;
        // SAFETY: kept blocks came from malloc and are no longer in use.
        unsafe { libc::free(old as *mut c_void) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_freed_large_block_is_handed_out_again_and_small_ones_are_not_kept() {
        let a = alloc(3 << 20);
        // SAFETY: `a` holds 3 MiB.
        unsafe { std::ptr::write_bytes(a.cast::<u8>(), 7, 3 << 20) };
        free(a);
        // 2.5 MiB rounds up to 3: the same block.
        let b = alloc((5 << 20) / 2);
        assert_eq!(a, b);
        free(b);
        // At most a quarter larger than asked: a 2 MiB request takes a fresh block.
        let c = alloc(2 << 20);
        assert_ne!(c, b);
        free(c);
        let small = alloc(100);
        assert!(!small.is_null() && (small as usize).is_multiple_of(16));
        free(small);
        assert!(idle().iter().all(|&(_, size)| size >= LARGE));
        assert!(idle().iter().map(|b| b.1).sum::<usize>() <= KEEP);
    }

    #[test]
    fn only_lossless_scanline_exrs_qualify() {
        assert!(qualifies("openexr", Some("zip"), false));
        assert!(qualifies("openexr", Some("piz"), false));
        assert!(!qualifies("openexr", Some("dwaa:45"), false));
        assert!(!qualifies("openexr", Some("zip"), true));
        assert!(!qualifies("tiff", Some("zip"), false));
        assert!(!qualifies("openexr", None, false));
    }
}
