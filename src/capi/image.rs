//! Host-owned images: a pointer, a sample format and signed byte strides, read into packed
//! planes before a denoise and written back after it.

use super::status::Failure;
use half::f16;

/// Sample type and channels per pixel of a host image.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(clippy::enum_variant_names)] // the C names (KPCN_FORMAT_FLOAT, …) come from these
pub enum KpcnFormat {
    /// 1 × 32-bit float.
    KpcnFormatFloat = 1,
    /// 3 × 32-bit float.
    KpcnFormatFloat3 = 3,
    /// 4 × 32-bit float (the fourth, e.g. alpha, is neither read nor written).
    KpcnFormatFloat4 = 4,
    /// 1 × 16-bit half float. Written outputs saturate at ±65504, half's largest finite
    /// value (never inf).
    KpcnFormatHalf = 0x101,
    /// 3 × 16-bit half float.
    KpcnFormatHalf3 = 0x103,
    /// 4 × 16-bit half float (the fourth is neither read nor written).
    KpcnFormatHalf4 = 0x104,
}

impl KpcnFormat {
    /// The format with this integer value; C enums arrive as plain integers.
    pub(crate) fn from_i32(v: i32) -> Option<Self> {
        use KpcnFormat::*;
        [KpcnFormatFloat, KpcnFormatFloat3, KpcnFormatFloat4, KpcnFormatHalf, KpcnFormatHalf3, KpcnFormatHalf4]
            .into_iter()
            .find(|f| *f as i32 == v)
    }

    fn channels(self) -> usize {
        (self as usize) & 0xff
    }

    fn sample_bytes(self) -> usize {
        if (self as i32) & 0x100 != 0 { 2 } else { 4 }
    }
}

/// An image in host memory: sample `c` of pixel `(x, y)` is at
/// `ptr + y * row_stride + x * pixel_stride + c * sample_bytes`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct HostImage {
    ptr: *mut u8,
    format: KpcnFormat,
    pub width: usize,
    pub height: usize,
    pixel_stride: isize,
    row_stride: isize,
}

// SAFETY: the host promises the memory stays valid and unshared while a call runs (kpcn.h says so).
unsafe impl Send for HostImage {}

impl HostImage {
    /// Checks a host's description. Strides of 0 mean packed; negative ones run backwards
    /// (bottom-up rows). Pixels may not overlap, which for an output would be a race.
    pub fn new(
        name: &str,
        ptr: *mut u8,
        format: i32,
        width: usize,
        height: usize,
        pixel_stride: isize,
        row_stride: isize,
    ) -> Result<HostImage, Failure> {
        let bad = |what: String| Failure::invalid(format!("image `{name}`: {what}"));
        if ptr.is_null() {
            return Err(bad("the pointer is NULL".into()));
        }
        let format = KpcnFormat::from_i32(format).ok_or_else(|| bad(format!("unknown format {format}")))?;
        if width == 0 || height == 0 {
            return Err(bad(format!("is {width}x{height}; give at least one pixel")));
        }
        let pixel_bytes = format.channels() * format.sample_bytes();
        let pixel_stride = if pixel_stride == 0 { pixel_bytes as isize } else { pixel_stride };
        if pixel_stride.unsigned_abs() < pixel_bytes {
            return Err(bad(format!("pixel stride {pixel_stride} is smaller than a pixel ({pixel_bytes} bytes)")));
        }
        let row_bytes = width
            .checked_mul(pixel_stride.unsigned_abs())
            .filter(|&b| b <= isize::MAX as usize)
            .ok_or_else(|| bad(format!("{width} pixels of {pixel_stride} bytes overflow")))?;
        let row_stride = if row_stride == 0 { (row_bytes as isize) * pixel_stride.signum() } else { row_stride };
        if height > 1 && row_stride.unsigned_abs() < row_bytes {
            return Err(bad(format!(
                "row stride {row_stride} is smaller than a row ({row_bytes} bytes): rows overlap"
            )));
        }
        // Every offset the image reaches must be an isize.
        let span = |n: usize, stride: isize| (n as isize - 1).checked_mul(stride);
        let (Some(a), Some(b)) = (span(width, pixel_stride), span(height, row_stride)) else {
            return Err(bad("its strides overflow the address space".into()));
        };
        if a.checked_add(b).and_then(|v| v.checked_add(pixel_bytes as isize)).is_none() {
            return Err(bad("its strides overflow the address space".into()));
        }
        Ok(HostImage { ptr, format, width, height, pixel_stride, row_stride })
    }

    fn at(&self, x: usize, y: usize, c: usize) -> *mut u8 {
        let offset = y as isize * self.row_stride + x as isize * self.pixel_stride;
        // In bounds of the host's buffer by the checks in `new` and the host's promise.
        self.ptr.wrapping_offset(offset + (c * self.format.sample_bytes()) as isize)
    }

    /// Rows `rows` of its first `channels` channels as packed planes.
    pub fn read_rows(&self, channels: usize, rows: std::ops::Range<usize>) -> Vec<Vec<f32>> {
        (0..channels.min(self.format.channels()))
            .map(|c| {
                let mut plane = Vec::with_capacity(self.width * rows.len());
                for y in rows.clone() {
                    for x in 0..self.width {
                        let p = self.at(x, y, c);
                        // SAFETY: `p` lies inside the host's image (see `new`); unaligned reads
                        // because hosts may pack pixels at odd byte strides.
                        plane.push(unsafe {
                            match self.format.sample_bytes() {
                                2 => f16::from_bits(std::ptr::read_unaligned(p as *const u16)).to_f32(),
                                _ => std::ptr::read_unaligned(p as *const f32),
                            }
                        });
                    }
                }
                plane
            })
            .collect()
    }

    /// Writes RGB planes into its first three channels (or the first for a 1-channel image).
    pub fn write(&self, rgb: &[Vec<f32>; 3]) {
        self.write_rows(rgb, 0..self.height);
    }

    /// Writes RGB planes of rows `rows` (packed from the first of them) into those rows.
    pub fn write_rows(&self, rgb: &[Vec<f32>; 3], rows: std::ops::Range<usize>) {
        for (c, plane) in rgb.iter().enumerate().take(self.format.channels()) {
            for y in rows.clone() {
                for x in 0..self.width {
                    let (p, v) = (self.at(x, y, c), plane[(y - rows.start) * self.width + x]);
                    // SAFETY: as in `read`.
                    unsafe {
                        match self.format.sample_bytes() {
                            // Saturated: a highlight above half's range stays the
                            // brightest finite half instead of becoming inf.
                            2 => std::ptr::write_unaligned(
                                p as *mut u16,
                                f16::from_f32(v.clamp(-f16::MAX.to_f32(), f16::MAX.to_f32())).to_bits(),
                            ),
                            _ => std::ptr::write_unaligned(p as *mut f32, v),
                        }
                    }
                }
            }
        }
    }

    /// Channels per pixel.
    pub fn channels(&self) -> usize {
        self.format.channels()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_outputs_saturate_instead_of_overflowing_to_inf() {
        let mut buf = [0u8; 2 * 3];
        let img = HostImage::new("x", buf.as_mut_ptr(), KpcnFormat::KpcnFormatHalf3 as i32, 1, 1, 0, 0).unwrap();
        img.write(&[vec![1e6], vec![-7e4], vec![2.0]]);
        assert_eq!(img.read_rows(3, 0..1), vec![vec![65504.0], vec![-65504.0], vec![2.0]]);
    }

    #[test]
    fn bottom_up_half_images_round_trip() {
        // 2×2, 4 halves per pixel, rows bottom-up with 2 bytes of padding per row.
        let mut buf = [0u8; 2 * 18];
        let top = buf[18..].as_mut_ptr();
        let img = HostImage::new("x", top, KpcnFormat::KpcnFormatHalf4 as i32, 2, 2, 8, -18).unwrap();
        let rgb = [vec![1.0, 2.0, 3.0, 4.0], vec![0.5; 4], vec![-1.0; 4]];
        img.write(&rgb);
        assert_eq!(img.read_rows(3, 0..2), rgb.to_vec());
        assert_eq!(img.read_rows(3, 1..2), rgb.map(|p| p[2..].to_vec()).to_vec(), "a band of rows");
        // The top row lies at the end of the buffer.
        assert_eq!(f16::from_bits(u16::from_le_bytes([buf[18], buf[19]])).to_f32(), 1.0);
        assert_eq!(f16::from_bits(u16::from_le_bytes([buf[0], buf[1]])).to_f32(), 3.0);
    }

    #[test]
    fn bad_descriptions_are_refused() {
        let mut b = [0f32; 16];
        let p = b.as_mut_ptr() as *mut u8;
        let new = |f, w, h, ps, rs| HostImage::new("x", p, f, w, h, ps, rs).map(|_| ()).map_err(|e| e.message);
        assert!(new(3, 2, 2, 0, 0).is_ok());
        assert!(new(2, 2, 2, 0, 0).unwrap_err().contains("unknown format 2"));
        assert!(new(3, 2, 2, 8, 0).unwrap_err().contains("pixel stride 8"));
        assert!(new(3, 2, 2, 12, 12).unwrap_err().contains("rows overlap"));
        assert!(new(3, 0, 2, 0, 0).unwrap_err().contains("0x2"));
        assert!(new(3, 2, 2, isize::MAX / 2, 0).is_err());
        assert!(HostImage::new("x", std::ptr::null_mut(), 3, 2, 2, 0, 0).is_err());
    }
}
