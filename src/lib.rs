//! mixvol: a Vulkan-native, explicitly memory-managed volume ray-caster.
#![warn(missing_docs, unsafe_op_in_unsafe_fn, clippy::undocumented_unsafe_blocks)]

pub mod volume;
