//! The back end of the method, steps 6–9: keyframes, Intensity Scan Context place recognition,
//! geometric verification of loop candidates, and the pose graph, driven one keyframe at a
//! time by [`BackEnd`]. Pure and deterministic like the rest of `core`: no threads, no clocks;
//! the caller runs it on its own thread and times its stages through a hook.

pub mod g2o;
pub mod pose_graph;
mod sparse;
