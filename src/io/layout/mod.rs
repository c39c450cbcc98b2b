//! The layered-EXR contract (ARCHITECTURE.md §Layout): which channels of a file hold which KPCN input.
//!
//! A [`Layout`] is a renderer's naming convention; a [`Mapping`] is a layout applied to
//! one file's channel names, saying for every input whether it is present, derived from
//! other passes, estimated, or missing. [`Mapping::extract`] turns a frame into
//! [`KpcnInputs`], the planes the denoiser consumes.

mod filters;
mod inputs;
mod mapping;
mod source;

pub use filters::{box3, spatial_variance};
pub use inputs::{KpcnInputs, Remainder};
pub use mapping::Mapping;
pub use source::{Entry, MeanStatus, Source, VarianceSource, VarianceStatus};

use std::fmt;
use std::str::FromStr;

/// A renderer's naming convention for the KPCN inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layout {
    /// The KPCN training-set layout: `R,G,B`, `diffuse.R`, `diffuseVariance.Z`, …
    Native,
    /// Blender Cycles multilayer passes (`ViewLayer.DiffDir.R` or `Diffuse Direct`).
    Cycles,
    /// RenderMan `denoise_batch` AOVs (`Ci`, `mse`, `diffuse_mse`, `zfiltered`, …).
    RenderMan,
}

impl Layout {
    /// Every layout, in detection-preference order.
    pub const ALL: [Layout; 3] = [Layout::Native, Layout::Cycles, Layout::RenderMan];

    /// Command-line name.
    pub fn name(self) -> &'static str {
        match self {
            Layout::Native => "native",
            Layout::Cycles => "cycles",
            Layout::RenderMan => "renderman",
        }
    }

    fn hint(self) -> &'static str {
        match self {
            Layout::Native => {
                "write kpcn's native AOVs (R,G,B, diffuse, specular, albedo, normal, depth and their …Variance channels), or choose the renderer's layout (cycles or renderman)"
            }
            Layout::Cycles => {
                "enable the Combined, Diffuse Direct/Indirect/Color, Normal and Z passes in Blender's View Layer properties and save as multilayer EXR"
            }
            Layout::RenderMan => {
                "add the denoise AOVs (Ci, mse, diffuse, diffuse_mse, specular, specular_mse, albedo, albedo_var, normal, normal_var, zfiltered, zfiltered_var) to the display"
            }
        }
    }
}

impl fmt::Display for Layout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Layout::ALL
            .into_iter()
            .find(|l| l.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown layout `{s}` (choose native, cycles or renderman)"))
    }
}

/// The quantities of ARCHITECTURE.md §Layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Beauty = diffuse + specular.
    Color,
    /// Diffuse radiance (albedo not divided out).
    Diffuse,
    /// Everything not diffuse.
    Specular,
    /// Diffuse reflectance at the first hit.
    Albedo,
    /// Shading normal at the first hit.
    Normal,
    /// Distance camera → first hit.
    Depth,
    /// Fraction of unoccluded light samples at the first hit.
    Visibility,
}

impl Quantity {
    /// All quantities in report order.
    pub const ALL: [Quantity; 7] = [
        Quantity::Color,
        Quantity::Diffuse,
        Quantity::Specular,
        Quantity::Albedo,
        Quantity::Normal,
        Quantity::Depth,
        Quantity::Visibility,
    ];

    /// The layer name of ARCHITECTURE.md §Layout (`color` is stored as root `R,G,B`).
    pub fn name(self) -> &'static str {
        match self {
            Quantity::Color => "color",
            Quantity::Diffuse => "diffuse",
            Quantity::Specular => "specular",
            Quantity::Albedo => "albedo",
            Quantity::Normal => "normal",
            Quantity::Depth => "depth",
            Quantity::Visibility => "visibility",
        }
    }

    /// Channels per pixel.
    pub fn components(self) -> usize {
        match self {
            Quantity::Depth | Quantity::Visibility => 1,
            _ => 3,
        }
    }

    /// Whether the network needs it. Visibility is recorded but is not a network input.
    pub fn required(self) -> bool {
        self != Quantity::Visibility
    }
}
