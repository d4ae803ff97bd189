//! Reused work buffers: resized per call, keeping their capacity, so a steady state allocates
//! nothing.

/// Resizes `buf` to `len` zeros, for a pass that accumulates into it.
pub fn zeroed(buf: &mut Vec<f32>, len: usize) {
    buf.clear();
    buf.resize(len, 0.0);
}

/// Resizes `buf` to `len` without clearing what the next pass overwrites anyway.
pub fn sized(buf: &mut Vec<f32>, len: usize) {
    buf.resize(len, 0.0);
}
