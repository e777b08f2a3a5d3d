//! Vertex colours: the canonical field volume-rendered along a short ray down each
//! vertex's normal, what a camera facing the vertex sees there.

use glam::Vec3;

use crate::ExportError;
use crate::canonical::{CanonicalSubject, Radiance};
use crate::surface::Surface;

/// Samples of the colour ray along each vertex's normal.
const COLOUR_SAMPLES: usize = 12;
/// The colour ray's half length, in cells of the surface grid: from this far outside the
/// vertex to as far inside.
const COLOUR_REACH_CELLS: f32 = 1.5;

/// Each vertex's colour: the field volume-rendered along a short ray down its normal
/// (from 1.5 grid cells outside to as far inside), normalised by the
/// ray's opacity, so a vertex gets the colour a camera facing it would see there.
/// Where the ray gathers no opacity, the field's colour at the vertex.
pub fn surface_colours(
    subject: &CanonicalSubject,
    surface: &Surface,
) -> Result<Vec<[f32; 3]>, ExportError> {
    let reach = COLOUR_REACH_CELLS * surface.cell;
    let step = 2.0 * reach / COLOUR_SAMPLES as f32;
    let points: Vec<Vec3> = surface
        .positions
        .iter()
        .zip(&surface.normals)
        .flat_map(|(&p, &n)| {
            (0..COLOUR_SAMPLES).map(move |k| p + n * (reach - (k as f32 + 0.5) * step))
        })
        .collect();
    let at_vertex = subject.radiance(&surface.positions)?;
    let along = subject.radiance(&points)?;
    Ok(along
        .chunks_exact(COLOUR_SAMPLES)
        .zip(&at_vertex)
        .map(|(ray, fallback)| composite(ray, step).unwrap_or(fallback.rgb))
        .collect())
}

/// Front-to-back compositing of `samples` a `step` apart, normalised by the opacity;
/// `None` if they gather almost none.
fn composite(samples: &[Radiance], step: f32) -> Option<[f32; 3]> {
    let mut transmittance = 1.0f32;
    let mut rgb = [0.0f32; 3];
    for s in samples {
        let alpha = 1.0 - (-s.sigma * step).exp();
        for c in 0..3 {
            rgb[c] += transmittance * alpha * s.rgb[c];
        }
        transmittance *= 1.0 - alpha;
    }
    let opacity = 1.0 - transmittance;
    (opacity > 1e-3).then(|| rgb.map(|c| (c / opacity).clamp(0.0, 1.0)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compositing_is_normalised_and_front_first() {
        let red = Radiance {
            sigma: 1e4,
            rgb: [1.0, 0.0, 0.0],
        };
        let blue = Radiance {
            sigma: 1e4,
            rgb: [0.0, 0.0, 1.0],
        };
        let empty = Radiance::default();
        // An opaque red layer hides the blue one behind it.
        let c = composite(&[empty, red, blue], 0.01).unwrap();
        assert!(c[0] > 0.99 && c[2] < 0.01, "{c:?}");
        // A faint layer alone still gives its own colour, not a darkened one.
        let faint = Radiance {
            sigma: 1.0,
            rgb: [0.2, 0.4, 0.6],
        };
        let c = composite(&[faint], 0.01).unwrap();
        assert!((c[1] - 0.4).abs() < 1e-4, "{c:?}");
        assert_eq!(composite(&[empty, empty], 0.01), None);
    }
}
