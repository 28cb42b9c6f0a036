//! WGSL compute engine for the likelihood stages.
