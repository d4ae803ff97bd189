//! PF-net's observation model: configuration, the three parts (map encoder, observation
//! encoder, joint stage), the spatial transformer that cuts each particle's local map, the
//! training loss, and the Keras reference check.

mod banked;
mod batch;
mod config;
mod feature_cache;
mod joint;
mod loss;
mod map_encoder;
mod model;
mod obs_encoder;
mod observation;
mod reference;
mod saved;
mod scan_on_map;
mod spatial_transformer;
mod stage;
mod train_step;
mod widen;

pub use batch::{MAP_ENCODER_CHUNK, PARTICLE_CHUNK, Workspaces};
pub use config::{ConvBranch, PfNetConfig, ScanOnMap, WideView};
pub use feature_cache::{FeatureBank, FeatureCacheSpec};
pub use loss::{MixtureLoss, PoseLoss};
pub use model::{MapInput, ParamCounts, PfNet, Workspace, is_map_encoder_param};
pub use observation::{DEPTH_BIN_M, Observation, depth_image};
pub use reference::{ReferenceError, VerifyReport, from_keras_layout, load_reference_model, verify};
pub use saved::PfNetFileError;
pub use spatial_transformer::{LocalMapSpec, MapView, crop_local_map_stack, crop_local_maps};
pub use train_step::{GradBuffers, StepBatch};
