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

impl KpcnInputs {
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
}
