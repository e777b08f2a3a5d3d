//! Rendered frames as response bodies: PNG, raw RGB, or a zip of PNGs.

use std::io::{Cursor, Write};

use image::ImageEncoder;
use image::codecs::png::PngEncoder;

use super::error::RequestError;
use talkin_render::avatar::RenderedFrame;

/// An encoded frame and what the response headers say about it.
pub struct Encoded {
    pub bytes: Vec<u8>,
    pub content_type: &'static str,
    pub width: u32,
    pub height: u32,
    pub samples: usize,
    pub seconds: f64,
}

fn encoded(frame: &RenderedFrame, bytes: Vec<u8>, content_type: &'static str) -> Encoded {
    Encoded {
        bytes,
        content_type,
        width: frame.width,
        height: frame.height,
        samples: frame.samples,
        seconds: frame.seconds,
    }
}

/// The colour as an 8-bit RGB PNG.
pub fn png(frame: &RenderedFrame) -> Result<Encoded, RequestError> {
    let image = frame.to_image();
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes)
        .write_image(
            image.as_raw(),
            frame.width,
            frame.height,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| RequestError::Render(format!("PNG encoding: {e}")))?;
    Ok(encoded(frame, bytes, "image/png"))
}

/// The colour as row-major 8-bit RGB.
pub fn raw(frame: &RenderedFrame) -> Encoded {
    encoded(
        frame,
        frame.to_image().into_raw(),
        "application/octet-stream",
    )
}

/// `frame_00000.png`, ... in a zip, stored (PNGs are compressed already).
pub fn zip_frames(pngs: &[Vec<u8>]) -> Result<Vec<u8>, RequestError> {
    let fail = |e: &dyn std::fmt::Display| RequestError::Render(format!("zip: {e}"));
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let options =
        zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for (i, png) in pngs.iter().enumerate() {
        zip.start_file(format!("frame_{i:05}.png"), options)
            .map_err(|e| fail(&e))?;
        zip.write_all(png).map_err(|e| fail(&e))?;
    }
    Ok(zip.finish().map_err(|e| fail(&e))?.into_inner())
}
