//! A trained avatar ([`talkin_avatar::Avatar`]) at work: [`RenderFrame`] renders one
//! frame of it, every pixel's ray through the frame's sampler and the field in chunks.

mod forwards;
mod frame;

pub use frame::{
    DEVICE_FORWARD_SAMPLES_MAX, MAX_RENDER_PIXELS, RENDER_CHUNK_RAYS, RENDER_CHUNK_SAMPLES,
    RenderFrame, RenderedFrame, forward_samples_on,
};
