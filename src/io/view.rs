//! Borrowed in-memory images with strides, for hosts that hold their own buffers (the
//! OIDN-style API: each image set by name with pixel and row strides).

use super::error::IoError;
use super::layout::{KpcnInputs, Layout, Mapping, MeanStatus, Quantity};
use super::{FrameBuffers, SampleFormat};

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
}

/// The images a host hands to the denoiser. Variances are of the pixel mean; absent ones
/// are estimated as for a file without them.
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

/// The images a host may hand over by name: the means, then the variances (of the pixel
/// mean; 1 channel, or 3 averaged). Names follow the native layout's layers (SPEC §3).
pub const IMAGE_NAMES: [&str; 12] = [
    "color",
    "diffuse",
    "specular",
    "albedo",
    "normal",
    "depth",
    "colorVariance",
    "diffuseVariance",
    "specularVariance",
    "albedoVariance",
    "normalVariance",
    "depthVariance",
];

/// In-memory images by name, turned into the network's inputs by the same mapping as a file
/// in the native layout: `color` or `specular` is derived from the other two, and absent
/// variances are estimated exactly as for a file without them.
#[derive(Debug, Clone)]
pub struct NamedImages {
    frame: FrameBuffers,
}

impl NamedImages {
    /// No images yet, for a `width`×`height` frame.
    pub fn new(width: usize, height: usize) -> Self {
        let mut frame = FrameBuffers::new(width, height);
        frame.source = Some("<memory>".into());
        NamedImages { frame }
    }

    /// Channels an image called `name` must have: 3 for colours, normal; 1 for depth; 1 or 3
    /// for a variance. `None` for an unknown name.
    pub fn channels_of(name: &str) -> Option<&'static [usize]> {
        match name {
            _ if name.ends_with("Variance") && IMAGE_NAMES.contains(&name) => Some(&[1, 3]),
            "depth" => Some(&[1]),
            _ if IMAGE_NAMES.contains(&name) => Some(&[3]),
            _ => None,
        }
    }

    /// Sets image `name` from packed planes (one per channel), replacing an earlier one.
    pub fn insert(&mut self, name: &str, planes: Vec<Vec<f32>>) -> Result<(), IoError> {
        let bad = |msg: String| IoError::BadImage { name: name.into(), msg };
        let Some(allowed) = Self::channels_of(name) else {
            return Err(bad(format!("is not an input (use one of {})", IMAGE_NAMES.join(", "))));
        };
        if !allowed.contains(&planes.len()) {
            return Err(bad(format!("has {} channels, needs {}", planes.len(), allowed[0])));
        }
        let (w, h) = (self.frame.width(), self.frame.height());
        if let Some(p) = planes.iter().find(|p| p.len() != w * h) {
            return Err(bad(format!("has {} pixels, the frame is {w}x{h}", p.len())));
        }
        self.remove(name);
        for (channel, data) in Self::channel_names(name, planes.len()).iter().zip(planes) {
            self.frame.insert(channel, SampleFormat::Float, data)?;
        }
        Ok(())
    }

    /// Forgets image `name`; whether it was set.
    pub fn remove(&mut self, name: &str) -> bool {
        let mut any = false;
        for k in [1, 3] {
            for c in Self::channel_names(name, k) {
                any |= self.frame.remove(&c).is_some();
            }
        }
        any
    }

    /// The native-layout channels of image `name` with `k` channels.
    fn channel_names(name: &str, k: usize) -> Vec<String> {
        let suffixes: &[&str] = if k == 1 { &["Z"] } else { &["R", "G", "B"] };
        suffixes.iter().map(|s| if name == "color" { s.to_string() } else { format!("{name}.{s}") }).collect()
    }

    /// Width and height.
    pub fn size(&self) -> (usize, usize) {
        (self.frame.width(), self.frame.height())
    }

    /// The network's inputs; an error names every missing image.
    pub fn inputs(&self) -> Result<KpcnInputs, IoError> {
        let mapping = Mapping::new(self.frame.channel_names(), Some(Layout::Native));
        let mut missing: Vec<&str> = Vec::new();
        for q in Quantity::ALL.into_iter().filter(|q| q.required()) {
            if mapping.entry_for(q).mean_status() == MeanStatus::Missing {
                missing.push(q.name());
            }
        }
        // With colour and specular both absent, both are reported; one of them suffices.
        if !missing.is_empty() {
            return Err(IoError::MissingImages { missing: missing.iter().map(|m| m.to_string()).collect() });
        }
        mapping.extract(&self.frame)
    }
}

impl KpcnInputs {
    /// Builds the network's inputs from in-memory images, checking sizes and strides.
    pub fn from_views(v: &InputViews) -> Result<KpcnInputs, IoError> {
        let (w, h) = (v.diffuse.width, v.diffuse.height);
        let mut images = NamedImages::new(w, h);
        let views = [
            ("color", v.color),
            ("diffuse", Some(v.diffuse)),
            ("specular", v.specular),
            ("albedo", Some(v.albedo)),
            ("normal", Some(v.normal)),
            ("depth", Some(v.depth)),
            ("diffuseVariance", v.diffuse_variance),
            ("specularVariance", v.specular_variance),
            ("albedoVariance", v.albedo_variance),
            ("normalVariance", v.normal_variance),
            ("depthVariance", v.depth_variance),
        ];
        for (name, view) in views {
            let Some(view) = view else { continue };
            let k = NamedImages::channels_of(name).map_or(1, |c| c[0]);
            view.check(name, w, h, k)?;
            images.insert(name, (0..k).map(|c| view.plane(c)).collect())?;
        }
        images.inputs()
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
