//! export: a trained avatar as a skinned glTF 2.0 binary (`.glb`) that game engines and
//! three.js can animate. The [`surface`] is the level set of the canonical density (the
//! field evaluated in the canonical pose exactly as the renderer would, see [`canonical`]),
//! its vertex colours are the field's radiance seen along each vertex's normal, the
//! [`rig`] is the subject's SMPL-X skeleton bound in the canonical pose, each vertex
//! carries the four largest learned skinning weights ([`weights`]), and a motion becomes
//! a glTF animation on the joints ([`animation`]). [`glb`] writes the document.
//!
//! Must not know about training, the server or the command line; it reads a loaded
//! [`talkin_avatar::Avatar`] and never writes a checkpoint.

pub mod animation;
pub mod canonical;
pub mod colours;
pub mod glb;
pub mod rig;
pub mod surface;
pub mod weights;

use std::time::Instant;

use talkin_avatar::{Avatar, AvatarError};

pub use canonical::CanonicalSubject;
pub use surface::{Surface, SurfaceOptions};
pub use weights::SkinWeights;

/// Cells along the longest side of the subject's canonical box by default.
pub const DEFAULT_RESOLUTION: u32 = 128;
/// The resolutions `talkin export` accepts: below 16 cells a head is two cells high;
/// above 512 the grid holds over 10^8 points for a 2 m person (hours on a CPU).
pub const RESOLUTIONS: std::ops::RangeInclusive<u32> = 16..=512;

/// Why an avatar could not be exported.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Avatar(#[from] AvatarError),
    #[error("field: {0}")]
    Field(#[from] talkin_nets::NetsError),
    #[error("resolution {0} is not in {start}..={end} cells", start = RESOLUTIONS.start(), end = RESOLUTIONS.end())]
    Resolution(u32),
    #[error(
        "the level set of the canonical density is empty (level {level}): an untrained or diverged field?"
    )]
    EmptySurface { level: f32 },
    #[error("the field produced a non-finite density or colour (a diverged checkpoint?)")]
    NonFinite,
    #[error("glTF: {0}")]
    Gltf(String),
}

/// A subject's exported avatar before it is written: mesh, colours, rig and weights.
#[derive(Clone, Debug)]
pub struct ExportedAvatar {
    /// Subject name.
    pub subject: String,
    pub surface: Surface,
    /// Per vertex, in [0, 1].
    pub colours: Vec<[f32; 3]>,
    pub skin: SkinWeights,
    pub rig: rig::Rig,
    /// Wall time of the surface, colours and weights.
    pub seconds: f64,
}

/// Exports subject `name` of `avatar` at `opts` (resolution checked against
/// [`RESOLUTIONS`]).
pub fn export_avatar(
    avatar: &Avatar,
    name: &str,
    opts: &SurfaceOptions,
) -> Result<ExportedAvatar, ExportError> {
    if !RESOLUTIONS.contains(&opts.resolution) {
        return Err(ExportError::Resolution(opts.resolution));
    }
    let start = Instant::now();
    let subject = CanonicalSubject::new(avatar, name)?;
    let surface = surface::extract(&subject, opts)?;
    let colours = colours::surface_colours(&subject, &surface)?;
    let skin = weights::skin_weights(&subject, &surface.positions)?;
    Ok(ExportedAvatar {
        subject: name.to_string(),
        rig: rig::Rig::new(&subject.model().skeleton),
        surface,
        colours,
        skin,
        seconds: start.elapsed().as_secs_f64(),
    })
}
