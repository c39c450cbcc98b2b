//! The planes the denoiser consumes.

/// The KPCN inputs of one frame as planes (`width * height` each, row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct KpcnInputs {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Beauty RGB.
    pub color: [Vec<f32>; 3],
    /// Diffuse RGB.
    pub diffuse: [Vec<f32>; 3],
    /// Specular RGB.
    pub specular: [Vec<f32>; 3],
    /// Albedo RGB.
    pub albedo: [Vec<f32>; 3],
    /// Normal XYZ.
    pub normal: [Vec<f32>; 3],
    /// Depth.
    pub depth: Vec<f32>,
    /// Visibility, when the renderer wrote it.
    pub visibility: Option<Vec<f32>>,
    /// Variance of the mean of `color` (RGB average).
    pub color_variance: Vec<f32>,
    /// Variance of the mean of `diffuse`.
    pub diffuse_variance: Vec<f32>,
    /// Variance of the mean of `specular`.
    pub specular_variance: Vec<f32>,
    /// Variance of the mean of `albedo`.
    pub albedo_variance: Vec<f32>,
    /// Variance of the mean of `normal`.
    pub normal_variance: Vec<f32>,
    /// Variance of the mean of `depth`.
    pub depth_variance: Vec<f32>,
}

/// What a beauty holds beyond diffuse + specular (emission, volumes, anything a renderer
/// adds to the beauty only), over the rows of a frame: carried to the output undenoised,
/// so that the denoised beauty keeps it (see [`KpcnInputs::remainder`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Remainder {
    /// `color − (diffuse + specular)` per pixel and channel, or `None` when it is zero
    /// (within the rounding of the file's formats) everywhere.
    pub planes: Option<[Vec<f32>; 3]>,
    /// Pixels where it is not zero.
    pub pixels: usize,
    /// Its sum over pixels and channels (negative when the components exceed the beauty).
    pub sum: f64,
    /// The beauty's sum over the same rows, for reports.
    pub beauty: f64,
}

impl Remainder {
    /// How far the components exceed the beauty, in percent of the beauty's energy, when
    /// by more than 1 %: then the passes disagree (written from different renders or
    /// sample counts), since what a beauty holds beyond diffuse + specular (emission,
    /// volumes) only ever adds. `None` when they agree.
    pub fn disagreement(&self) -> Option<f64> {
        let excess = -100.0 * self.sum / self.beauty.abs().max(f64::MIN_POSITIVE);
        (self.pixels > 0 && excess > 1.0).then_some(excess)
    }

    /// The share of the beauty's energy beyond diffuse + specular, in percent.
    pub fn share(&self) -> f64 {
        100.0 * self.sum / self.beauty.abs().max(f64::MIN_POSITIVE)
    }

    /// Adds `other`'s counts and sums to this one's (a frame's report over its bands); the
    /// planes are not kept.
    pub fn absorb_counts(&mut self, other: &Remainder) {
        self.pixels += other.pixels;
        self.sum += other.sum;
        self.beauty += other.beauty;
    }
}

impl KpcnInputs {
    /// Planes of a frame's inputs with visibility: five RGB means, depth, visibility and
    /// six variances.
    pub const PLANES: usize = 5 * 3 + 2 + 6;

    /// Bytes of the inputs of a `width`×`height` frame.
    pub fn bytes(width: usize, height: usize) -> usize {
        Self::PLANES * 4 * width * height
    }

    /// Replaces every variance by the 3×3 spatial estimate of its mean
    /// ([`super::spatial_variance`]), exactly what a file without variances gives.
    pub fn estimate_variances_spatially(&mut self) {
        let (w, h) = (self.width, self.height);
        self.color_variance = super::spatial_variance(&self.color, w, h);
        self.diffuse_variance = super::spatial_variance(&self.diffuse, w, h);
        self.specular_variance = super::spatial_variance(&self.specular, w, h);
        self.albedo_variance = super::spatial_variance(&self.albedo, w, h);
        self.normal_variance = super::spatial_variance(&self.normal, w, h);
        self.depth_variance = super::spatial_variance(std::slice::from_ref(&self.depth), w, h);
    }

    /// The [`Remainder`] of rows `rows`: where the beauty differs from diffuse + specular
    /// by more than the rounding of half-float channels (a relative 1e-3), the difference.
    /// Zero for files whose beauty is the sum of its components or whose specular is the
    /// beauty minus the diffuse, so their output is exactly what it was.
    pub fn remainder(&self, rows: std::ops::Range<usize>) -> Remainder {
        let span = rows.start * self.width..rows.end * self.width;
        let mut out = Remainder::default();
        for (k, i) in span.clone().enumerate() {
            let mut kept = false;
            for c in 0..3 {
                let (col, d, s) = (self.color[c][i], self.diffuse[c][i], self.specular[c][i]);
                if col.is_finite() {
                    out.beauty += col as f64;
                }
                let diff = col - (d + s);
                if diff.is_finite() && diff.abs() > 1e-3 * (col.abs() + d.abs() + s.abs()) + 1e-6 {
                    // The planes exist only for a band that has a remainder somewhere.
                    let planes = out.planes.get_or_insert_with(|| std::array::from_fn(|_| vec![0f32; span.len()]));
                    planes[c][k] = diff;
                    out.sum += diff as f64;
                    kept = true;
                }
            }
            out.pixels += usize::from(kept);
        }
        out
    }
}
