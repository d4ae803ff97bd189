//! Our neural engine, in the manner of llm.c: fixed layers with `forward` and `backward` side by
//! side over flat NCHW `f32` slices, backward passes that accumulate (the element-wise activations
//! write theirs), parameters in one arena, Adam, safetensors checkpoints; PF-net and the SAC agent
//! on top. No ECS types in here.

pub mod activation;
pub mod adam;
pub mod buffers;
pub mod checkpoint;
pub mod conv;
pub mod dense;
pub mod gemm;
#[cfg(test)]
pub mod gradcheck;
pub mod layer_norm;
pub mod locally_connected;
pub mod params;
pub mod pfnet;
pub mod pool;
pub mod sac;

/// Elements per task of the engine's element-wise parallel loops (Adam, the Polyak average, sums
/// of gradient buffers). Fixed, so which element goes where never depends on the thread count.
pub const PARALLEL_SLICE: usize = 1 << 15;
