//! Borrowed in-memory images with strides, for hosts that hold their own buffers (the
//! OIDN-style API: each image set by name with pixel and row strides).

use super::error::IoError;
use super::layout::{KpcnInputs, spatial_variance};

/// Sample `(x, y, c)` is `data[y * row_stride + x * pixel_stride + c]` (strides in floats).
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// The samples.
    pub data: &'a [f32],
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
    /// Channels read per pixel (3 for RGB, 1 for depth and variances).
    pub channels: usize,
    /// Floats from one pixel to the next.
    pub pixel_stride: usize,
    /// Floats from one row to the next.
    pub row_stride: usize,
}

impl<'a> ImageView<'a> {
    /// A tightly packed image (`channels` floats per pixel, rows back to back).
    pub fn packed(data: &'a [f32], width: usize, height: usize, channels: usize) -> Self {
        ImageView { data, width, height, channels, pixel_stride: channels, row_stride: channels * width }
    }

    fn check(&self, name: &str, width: usize, height: usize, channels: usize) -> Result<(), IoError> {
        let err = |msg: String| IoError::BadImage { name: name.into(), msg };
        if (self.width, self.height) != (width, height) {
            return Err(err(format!("is {}x{}, the frame is {width}x{height}", self.width, self.height)));
        }
        if self.channels < channels || self.pixel_stride < self.channels {
            return Err(err(format!("needs {channels} channels per pixel within its pixel stride")));
        }
        if width > 0 && height > 0 {
            let last = (height - 1) * self.row_stride + (width - 1) * self.pixel_stride + channels - 1;
            if last >= self.data.len() {
                return Err(err(format!("strides reach sample {last} but the buffer holds {}", self.data.len())));
            }
        }
        Ok(())
    }

    /// Channel `c` as a packed plane.
    pub fn plane(&self, c: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            out.extend((0..self.width).map(|x| self.data[y * self.row_stride + x * self.pixel_stride + c]));
        }
        out
    }

    fn rgb(&self) -> [Vec<f32>; 3] {
        [self.plane(0), self.plane(1), self.plane(2)]
    }
}

/// The images a host hands to the denoiser. Variances are of the pixel mean; absent ones
/// are estimated spatially (3×3 local variance).
#[derive(Debug, Clone, Copy)]
pub struct InputViews<'a> {
    /// Beauty RGB (derived as diffuse + specular when absent).
    pub color: Option<ImageView<'a>>,
    /// Diffuse RGB.
    pub diffuse: ImageView<'a>,
    /// Specular RGB (derived as color − diffuse when absent).
    pub specular: Option<ImageView<'a>>,
    /// Albedo RGB.
    pub albedo: ImageView<'a>,
    /// Normal XYZ.
    pub normal: ImageView<'a>,
    /// Depth (1 channel).
    pub depth: ImageView<'a>,
    /// Variance of diffuse (1 channel).
    pub diffuse_variance: Option<ImageView<'a>>,
    /// Variance of specular.
    pub specular_variance: Option<ImageView<'a>>,
    /// Variance of albedo.
    pub albedo_variance: Option<ImageView<'a>>,
    /// Variance of normal.
    pub normal_variance: Option<ImageView<'a>>,
    /// Variance of depth.
    pub depth_variance: Option<ImageView<'a>>,
}

impl KpcnInputs {
    /// Builds the network's inputs from in-memory images, checking sizes and strides.
    pub fn from_views(v: &InputViews) -> Result<KpcnInputs, IoError> {
        let (w, h) = (v.diffuse.width, v.diffuse.height);
        let rgb = |name: &str, view: &ImageView| view.check(name, w, h, 3).map(|_| view.rgb());
        let diffuse = rgb("diffuse", &v.diffuse)?;
        let albedo = rgb("albedo", &v.albedo)?;
        let normal = rgb("normal", &v.normal)?;
        v.depth.check("depth", w, h, 1)?;
        let depth = v.depth.plane(0);
        let zip = |a: &[Vec<f32>; 3], b: &[Vec<f32>; 3], f: fn(f32, f32) -> f32| -> [Vec<f32>; 3] {
            std::array::from_fn(|c| a[c].iter().zip(&b[c]).map(|(x, y)| f(*x, *y)).collect())
        };
        let (color, specular) = match (&v.color, &v.specular) {
            (Some(c), Some(s)) => (rgb("color", c)?, rgb("specular", s)?),
            (Some(c), None) => {
                let color = rgb("color", c)?;
                let specular = zip(&color, &diffuse, |c, d| c - d);
                (color, specular)
            }
            (None, Some(s)) => {
                let specular = rgb("specular", s)?;
                (zip(&diffuse, &specular, |d, s| d + s), specular)
            }
            (None, None) => {
                return Err(IoError::BadImage { name: "specular".into(), msg: "give specular or color".into() });
            }
        };
        let variance = |name: &str, view: &Option<ImageView>, mean: &[Vec<f32>]| -> Result<Vec<f32>, IoError> {
            match view {
                Some(view) => view.check(name, w, h, 1).map(|_| view.plane(0)),
                None => Ok(spatial_variance(mean, w, h)),
            }
        };
        Ok(KpcnInputs {
            width: w,
            height: h,
            color_variance: spatial_variance(&color, w, h),
            diffuse_variance: variance("diffuse_variance", &v.diffuse_variance, &diffuse)?,
            specular_variance: variance("specular_variance", &v.specular_variance, &specular)?,
            albedo_variance: variance("albedo_variance", &v.albedo_variance, &albedo)?,
            normal_variance: variance("normal_variance", &v.normal_variance, &normal)?,
            depth_variance: variance("depth_variance", &v.depth_variance, std::slice::from_ref(&depth))?,
            color,
            diffuse,
            specular,
            albedo,
            normal,
            depth,
            visibility: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strided_views_read_the_right_samples() {
        // 2×2 RGBA rows padded to 10 floats.
        let data: Vec<f32> = (0..20).map(|i| i as f32).collect();
        let v = ImageView { data: &data, width: 2, height: 2, channels: 3, pixel_stride: 4, row_stride: 10 };
        assert_eq!(v.plane(0), [0.0, 4.0, 10.0, 14.0]);
        assert_eq!(v.plane(2), [2.0, 6.0, 12.0, 16.0]);
        assert!(v.check("x", 2, 2, 3).is_ok());
        let short = ImageView { data: &data[..16], ..v };
        assert!(short.check("x", 2, 2, 3).unwrap_err().to_string().contains("strides reach sample 16"));
        assert!(v.check("x", 3, 2, 3).is_err());
    }

    #[test]
    fn views_become_inputs_with_derived_specular_and_estimated_variance() {
        let (w, h) = (3, 2);
        let rgb = |v: f32| vec![v; w * h * 3];
        let (c, d, a, n, z) = (rgb(1.0), rgb(0.25), rgb(0.5), rgb(0.0), vec![2.0; w * h]);
        let views = InputViews {
            color: Some(ImageView::packed(&c, w, h, 3)),
            diffuse: ImageView::packed(&d, w, h, 3),
            specular: None,
            albedo: ImageView::packed(&a, w, h, 3),
            normal: ImageView::packed(&n, w, h, 3),
            depth: ImageView::packed(&z, w, h, 1),
            diffuse_variance: None,
            specular_variance: None,
            albedo_variance: None,
            normal_variance: None,
            depth_variance: None,
        };
        let k = KpcnInputs::from_views(&views).unwrap();
        assert_eq!(k.specular[1], vec![0.75; w * h]);
        assert_eq!(k.diffuse_variance, vec![0.0; w * h], "a constant image has no local variance");
    }
}
