//! zlib's one-shot calls (`compress`, `compress2`, `uncompress`), served by libdeflate in
//! the `kpcn` process.
//!
//! OpenEXR 3.1 (Debian 12's) deflates and inflates every ZIP and ZIPS chunk through these
//! three calls, and they were a third of a file command's CPU. libdeflate does the same
//! whole-buffer work about 2.2× faster when compressing at the same level (for a file as
//! large) and 4× faster when decompressing (`BENCHMARKS.md`, "Whole command: file to file,
//! sequences, C hosts"). Its output is a standard zlib stream, so every reader opens what we
//! write.
//!
//! The executable exports these symbols (`build.rs`), and the dynamic linker binds the
//! libraries' calls to the executable's definitions before libz's. Whatever libdeflate
//! does not finish (an output buffer smaller than its bound, a stream it rejects, a preset
//! dictionary) goes to libz's own function, found with `dlsym(RTLD_NEXT)`, so every error
//! code a caller sees is zlib's. The library, its C ABI and the Python module leave zlib
//! alone: a host's process is not ours to change.

use libdeflate_sys as ld;
use std::cell::RefCell;
use std::ffi::{CStr, c_int, c_ulong, c_void};
use std::sync::OnceLock;

const Z_OK: c_int = 0;
const Z_DEFAULT_COMPRESSION: c_int = -1;
/// zlib's default level, which `compress` and level −1 mean.
const DEFAULT_LEVEL: c_int = 6;

type Compress2 = unsafe extern "C" fn(*mut u8, *mut c_ulong, *const u8, c_ulong, c_int) -> c_int;
type Uncompress = unsafe extern "C" fn(*mut u8, *mut c_ulong, *const u8, c_ulong) -> c_int;

/// libz's definition of `name`: the next one after this executable's, or libz loaded here
/// where nothing loaded it (the process loads libz with OpenEXR, but not every test binary
/// links OpenEXR).
fn next(name: &CStr) -> *mut c_void {
    // SAFETY: dlsym and dlopen with NUL-terminated names; a null answer is handled by the caller.
    unsafe {
        let f = libc::dlsym(libc::RTLD_NEXT, name.as_ptr());
        if !f.is_null() {
            return f;
        }
        let libz = libc::dlopen(c"libz.so.1".as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL);
        if libz.is_null() { libz } else { libc::dlsym(libz, name.as_ptr()) }
    }
}

fn zlib_compress2() -> Option<Compress2> {
    static F: OnceLock<usize> = OnceLock::new();
    let f = *F.get_or_init(|| next(c"compress2") as usize);
    // SAFETY: libz's compress2 has this signature.
    (f != 0).then(|| unsafe { std::mem::transmute::<usize, Compress2>(f) })
}

fn zlib_uncompress() -> Option<Uncompress> {
    static F: OnceLock<usize> = OnceLock::new();
    let f = *F.get_or_init(|| next(c"uncompress") as usize);
    // SAFETY: libz's uncompress has this signature.
    (f != 0).then(|| unsafe { std::mem::transmute::<usize, Uncompress>(f) })
}

/// zlib's code for "insufficient memory", answered where libz itself cannot be loaded.
const Z_MEM_ERROR: c_int = -4;

/// This thread's libdeflate state: a compressor per level used, and one decompressor.
#[derive(Default)]
struct State {
    compressors: Vec<(c_int, *mut ld::libdeflate_compressor)>,
    decompressor: Option<*mut ld::libdeflate_decompressor>,
}

impl State {
    fn compressor(&mut self, level: c_int) -> *mut ld::libdeflate_compressor {
        if let Some(&(_, c)) = self.compressors.iter().find(|(l, _)| *l == level) {
            return c;
        }
        // SAFETY: allocating has no precondition; null (out of memory) is answered by libz.
        let c = unsafe { ld::libdeflate_alloc_compressor(level) };
        if !c.is_null() {
            self.compressors.push((level, c));
        }
        c
    }

    fn decompressor(&mut self) -> *mut ld::libdeflate_decompressor {
        if let Some(d) = self.decompressor {
            return d;
        }
        // SAFETY: as above.
        let d = unsafe { ld::libdeflate_alloc_decompressor() };
        if !d.is_null() {
            self.decompressor = Some(d);
        }
        d
    }
}

impl Drop for State {
    fn drop(&mut self) {
        // SAFETY: each pointer came from its allocator and is freed once.
        unsafe {
            for &(_, c) in &self.compressors {
                ld::libdeflate_free_compressor(c);
            }
            if let Some(d) = self.decompressor {
                ld::libdeflate_free_decompressor(d);
            }
        }
    }
}

thread_local! {
    static STATE: RefCell<State> = RefCell::new(State::default());
}

/// Deflates `source` into `dest` as a zlib stream at `level`; the stream's length, or
/// `None` where libdeflate cannot (no room, no memory, a level it lacks).
///
/// # Safety
/// `source` holds `source_len` bytes and `dest` has room for `dest_len`.
unsafe fn deflate(
    dest: *mut u8,
    dest_len: c_ulong,
    source: *const u8,
    source_len: c_ulong,
    level: c_int,
) -> Option<c_ulong> {
    let level = if level == Z_DEFAULT_COMPRESSION { DEFAULT_LEVEL } else { level };
    if !(0..=9).contains(&level) || dest.is_null() || source.is_null() {
        return None;
    }
    let n = STATE
        .try_with(|s| {
            let c = s.borrow_mut().compressor(level);
            if c.is_null() {
                return 0;
            }
            // SAFETY: the caller's buffers, as documented.
            unsafe {
                ld::libdeflate_zlib_compress(c, source.cast(), source_len as usize, dest.cast(), dest_len as usize)
            }
        })
        .unwrap_or(0);
    (n > 0).then_some(n as c_ulong)
}

/// Inflates the zlib stream in `source` into `dest`; the bytes written, or `None` where
/// libdeflate does not finish it.
///
/// # Safety
/// As [`deflate`].
unsafe fn inflate(dest: *mut u8, dest_len: c_ulong, source: *const u8, source_len: c_ulong) -> Option<c_ulong> {
    if dest.is_null() || source.is_null() || dest_len == 0 {
        return None;
    }
    STATE
        .try_with(|s| {
            let d = s.borrow_mut().decompressor();
            if d.is_null() {
                return None;
            }
            let (mut read, mut written) = (0usize, 0usize);
            // SAFETY: the caller's buffers; a stream followed by other bytes is read as
            // zlib reads it (up to its end), hence the `_ex` form.
            let r = unsafe {
                ld::libdeflate_zlib_decompress_ex(
                    d,
                    source.cast(),
                    source_len as usize,
                    dest.cast(),
                    dest_len as usize,
                    &mut read,
                    &mut written,
                )
            };
            (r == ld::libdeflate_result_LIBDEFLATE_SUCCESS).then_some(written as c_ulong)
        })
        .ok()
        .flatten()
}

/// zlib's `compress2`.
///
/// # Safety
/// zlib's contract: `dest_len` points at `dest`'s room and `source` holds `source_len` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn compress2(
    dest: *mut u8,
    dest_len: *mut c_ulong,
    source: *const u8,
    source_len: c_ulong,
    level: c_int,
) -> c_int {
    if !dest_len.is_null() {
        // SAFETY: zlib's contract, as documented.
        if let Some(n) = unsafe { deflate(dest, *dest_len, source, source_len, level) } {
            // SAFETY: checked non-null above; zlib's contract makes it writable.
            unsafe { *dest_len = n };
            return Z_OK;
        }
    }
    match zlib_compress2() {
        // SAFETY: the caller's arguments, passed on unchanged.
        Some(f) => unsafe { f(dest, dest_len, source, source_len, level) },
        None => Z_MEM_ERROR,
    }
}

/// zlib's `compress`: [`compress2`] at zlib's default level.
///
/// # Safety
/// As [`compress2`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn compress(
    dest: *mut u8,
    dest_len: *mut c_ulong,
    source: *const u8,
    source_len: c_ulong,
) -> c_int {
    // SAFETY: as documented.
    unsafe { compress2(dest, dest_len, source, source_len, Z_DEFAULT_COMPRESSION) }
}

/// zlib's `uncompress`.
///
/// # Safety
/// As [`compress2`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn uncompress(
    dest: *mut u8,
    dest_len: *mut c_ulong,
    source: *const u8,
    source_len: c_ulong,
) -> c_int {
    if !dest_len.is_null() {
        // SAFETY: zlib's contract, as documented.
        if let Some(n) = unsafe { inflate(dest, *dest_len, source, source_len) } {
            // SAFETY: checked non-null above; zlib's contract makes it writable.
            unsafe { *dest_len = n };
            return Z_OK;
        }
    }
    match zlib_uncompress() {
        // SAFETY: the caller's arguments, passed on unchanged.
        Some(f) => unsafe { f(dest, dest_len, source, source_len) },
        None => Z_MEM_ERROR,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bytes that deflate somewhat, like a float image's planes.
    fn sample(n: usize) -> Vec<u8> {
        (0..n).map(|i| ((i as f32 * 0.37).sin() * 40.0) as i8 as u8 ^ (i % 7) as u8).collect()
    }

    /// `compress2`-shaped `f` from `input` into `out`: zlib's code and the bytes written.
    fn at_level(f: Compress2, out: &mut [u8], input: &[u8], level: c_int) -> (c_int, usize) {
        let mut n = out.len() as c_ulong;
        // SAFETY: both slices are valid for the lengths passed.
        let code = unsafe { f(out.as_mut_ptr(), &mut n, input.as_ptr(), input.len() as c_ulong, level) };
        (code, n as usize)
    }

    /// `uncompress`-shaped `f` (or `compress`) from `input` into `out`, as [`at_level`].
    fn plain(f: Uncompress, out: &mut [u8], input: &[u8]) -> (c_int, usize) {
        let mut n = out.len() as c_ulong;
        // SAFETY: as in `at_level`.
        let code = unsafe { f(out.as_mut_ptr(), &mut n, input.as_ptr(), input.len() as c_ulong) };
        (code, n as usize)
    }

    #[test]
    fn our_streams_are_zlib_streams_and_zlib_streams_are_ours() {
        let raw = sample(300_000);
        let (libz_compress2, libz_uncompress) = (zlib_compress2().expect("libz"), zlib_uncompress().expect("libz"));
        let mut z = vec![0u8; raw.len() + raw.len() / 8 + 64];
        let mut back = vec![0u8; raw.len() + 10];
        for level in [-1, 0, 1, 4, 9] {
            // Ours, read back by libz.
            let (code, n) = at_level(compress2, &mut z, &raw, level);
            assert_eq!(code, Z_OK);
            let ours = z[..n].to_vec();
            assert_eq!(plain(libz_uncompress, &mut back, &ours), (Z_OK, raw.len()), "level {level}");
            assert_eq!(back[..raw.len()], raw[..], "level {level}");
            // libz's, read back by ours, with a trailing byte zlib ignores.
            let (code, n) = at_level(libz_compress2, &mut z, &raw, level);
            assert_eq!(code, Z_OK);
            if level != 0 {
                // Two encoders' streams of the same bytes: libdeflate made ours.
                assert_ne!(ours, z[..n], "level {level}: libz's own stream");
            }
            back.fill(0);
            assert_eq!(plain(uncompress, &mut back, &z[..n + 1]), (Z_OK, raw.len()), "level {level}");
            assert_eq!(back[..raw.len()], raw[..], "level {level}");
        }
    }

    #[test]
    fn what_libdeflate_cannot_do_gets_zlibs_answer() {
        const Z_STREAM_ERROR: c_int = -2;
        const Z_DATA_ERROR: c_int = -3;
        const Z_BUF_ERROR: c_int = -5;
        let raw = sample(100_000);
        let mut z = vec![0u8; raw.len() + 1024];
        let (code, n) = plain(compress, &mut z, &raw);
        assert_eq!(code, Z_OK);
        let z = &mut z[..n];
        // Too little room for the output.
        assert_eq!(plain(uncompress, &mut vec![0u8; raw.len() / 2], z).0, Z_BUF_ERROR);
        // No room to compress into.
        assert_eq!(at_level(compress2, &mut [0u8; 8], &raw, 4).0, Z_BUF_ERROR);
        // A level zlib refuses.
        assert_eq!(at_level(compress2, &mut vec![0u8; raw.len() + 1024], &raw, 12).0, Z_STREAM_ERROR);
        // A damaged stream.
        z[n / 2] ^= 0xff;
        z[n / 2 + 1] ^= 0x5a;
        assert_eq!(plain(uncompress, &mut vec![0u8; raw.len()], z).0, Z_DATA_ERROR);
    }
}
