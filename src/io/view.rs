//! In-memory images by name, for hosts that hold their own buffers (the C ABI's
//! OIDN-style API: each image set by name, then the network's inputs built from them).

use super::error::IoError;
use super::layout::{KpcnInputs, Layout, Mapping, MeanStatus, Quantity};
use super::{FrameBuffers, SampleFormat};

/// The images a host may hand over by name: the means, then the variances (of the pixel
/// mean; 1 channel, or 3 averaged). Names follow the native layout's layers (ARCHITECTURE.md §Layout).
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_images_become_inputs_with_derived_specular_and_estimated_variance() {
        let (w, h) = (3, 2);
        let rgb = |v: f32| vec![v; w * h * 3];
        let (c, d, a, n, z) = (rgb(1.0), rgb(0.25), rgb(0.5), rgb(0.0), vec![2.0; w * h]);
        let mut images = NamedImages::new(w, h);
        for (name, data, k) in
            [("color", &c, 3), ("diffuse", &d, 3), ("albedo", &a, 3), ("normal", &n, 3), ("depth", &z, 1)]
        {
            images.insert(name, data.chunks(w * h).take(k).map(<[f32]>::to_vec).collect()).unwrap();
        }
        let k = images.inputs().unwrap();
        assert_eq!(k.specular[1], vec![0.75; w * h]);
        assert_eq!(k.diffuse_variance, vec![0.0; w * h], "a constant image has no local variance");
    }
}
