//! WGSL compute engine for the likelihood stages: every particle of a frame evaluated on the
//! GPU through wgpu (Vulkan only), the twin of [`crate::likelihood::cpu`].
//!
//! One WGSL file per stage in `shaders/` (`colour.wgsl`, `gradient.wgsl`, `feature.wgsl`,
//! `combine.wgsl`), each prefixed with `common.wgsl`, which mirrors the shared Rust structs
//! ([`Particle`], [`TermLogs`](crate::likelihood::TermLogs),
//! [`LiftedFeature`](crate::likelihood::LiftedFeature),
//! [`LikelihoodParams`](crate::likelihood::LikelihoodParams) and [`FrameUniform`]); a unit
//! test checks that sizes and field offsets agree.
//!
//! Per frame the engine uploads the frame (one `u32` per pixel, `r | g << 8 | b << 16`), the
//! features lifted to 3D on the host (the CPU twin's own lift: it does not depend on the
//! particle) and the particles once (with each particle's `(sin, cos)` of `theta0 + rz`, and
//! each normal line's `(sin, cos)`, computed on the host exactly as the CPU twin does, so that
//! the pixel sets and the lines agree: WGSL's sin/cos are a few ulp off Rust's; the pixel sets
//! are then exact but for pixel centres whose inside test is a tie, which a compiler's fused
//! multiply-adds may tip), runs five kernels in one submission and reads back the `N`
//! [`TermLogs`](crate::likelihood::TermLogs) once:
//!
//! | kernel | shape |
//! |---|---|
//! | `gradient_image` | one invocation per pixel (16×16 tiles), exact `i32` |
//! | `colour` | one workgroup of 64 per particle: histogram in workgroup memory (atomics), Bhattacharyya reduced in the workgroup |
//! | `gradient_lines` | one invocation per (particle, line), writes the edge distance |
//! | `feature` | one invocation per particle, looping over the features |
//! | `combine` | one invocation per particle: line terms summed in line order, total |
//!
//! More than 65535 workgroups are laid out in 2D. Pipelines, the bind group and the buffers
//! are created once and grown when `N`, the frame or the feature count grows; a buffer of a
//! megabyte or more shrinks again after [`SHRINK_AFTER_CALLS`] calls in a row that need under
//! a quarter of it ([`GpuEngine::buffer_bytes`] says what they hold). On lavapipe the
//! colour kernel takes 75-90 % of the GPU time (workgroup atomics are slow in software),
//! the normal lines most of the rest; upload and readback are below a millisecond.
//!
//! A lost device is a clear error ([`LikelihoodError::DeviceLost`](crate::likelihood::LikelihoodError::DeviceLost)) from
//! that frame on; the engine itself does not switch to the CPU. The engines that
//! [`crate::likelihood::create_engine`] hands out (and so the tracker and the CLI) wrap it in a
//! [`FallbackEngine`](crate::likelihood::FallbackEngine), which does: the rest of the run goes on
//! on the CPU, with a one-line notice.

mod device;
mod engine;
pub mod workload;

pub use device::{ADAPTER_ENV, GpuDevice, adapter_names, named_adapter};
pub use engine::{DebugOutput, GpuEngine, SHRINK_AFTER_CALLS, StageTimes, TimingSource};

use bytemuck::{Pod, Zeroable};

use crate::likelihood::Particle;

/// Per-frame uniform of the shaders (what a frame adds to
/// [`LikelihoodParams`](crate::likelihood::LikelihoodParams)). Mirrored in `common.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct FrameUniform {
    /// The previous frame's estimate (feature term).
    pub prev: Particle,
    /// Frame width (pixels).
    pub width: u32,
    /// Frame height (pixels).
    pub height: u32,
    /// Number of particles.
    pub n: u32,
    /// Number of feature pairs.
    pub num_features: u32,
    /// Orientation of the ellipse in the reference pose (radians).
    pub theta0: f32,
    /// `H = round(line_half_length)` (rounded on the host, half away from zero as Rust's
    /// `f32::round`; WGSL's `round` rounds half to even).
    pub line_h: i32,
    /// Bit flags: [`FLAG_DEBUG_HIST`].
    pub flags: u32,
    /// `Σ_k q_k` of the colour model, summed in bin order in `f32` (as the CPU twin).
    pub q_sum: f32,
}

/// [`FrameUniform::flags`]: write each particle's histogram counts to the debug buffer.
pub const FLAG_DEBUG_HIST: u32 = 1;

/// Line distance reported for a line without an edge.
pub const NO_EDGE: i32 = -1;
/// Line distance reported for every line of a degenerate particle.
pub const SKIPPED: i32 = -2;

/// WGSL shared by every stage.
pub const COMMON_WGSL: &str = include_str!("../../../shaders/common.wgsl");
/// Colour histogram + Bhattacharyya.
pub const COLOUR_WGSL: &str = include_str!("../../../shaders/colour.wgsl");
/// Gradient image + normal lines.
pub const GRADIENT_WGSL: &str = include_str!("../../../shaders/gradient.wgsl");
/// Feature reprojection.
pub const FEATURE_WGSL: &str = include_str!("../../../shaders/feature.wgsl");
/// Combination into one log-likelihood per particle.
pub const COMBINE_WGSL: &str = include_str!("../../../shaders/combine.wgsl");

/// The stages, each with its file's source and its entry points.
pub const STAGES: [(&str, &str, &[&str]); 4] = [
    ("colour", COLOUR_WGSL, &["colour"]),
    (
        "gradient",
        GRADIENT_WGSL,
        &["gradient_image", "gradient_lines"],
    ),
    ("feature", FEATURE_WGSL, &["feature"]),
    ("combine", COMBINE_WGSL, &["combine"]),
];

/// The full source of a stage: `common.wgsl` followed by the stage's file.
pub fn stage_source(stage: &str) -> String {
    format!("{COMMON_WGSL}\n{stage}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::likelihood::{LiftedFeature, LikelihoodParams, TermLogs};
    use std::mem::{offset_of, size_of};

    fn parse_and_validate(src: &str) -> (naga::Module, naga::valid::ModuleInfo) {
        let module = naga::front::wgsl::parse_str(src).unwrap_or_else(|e| {
            panic!("WGSL parse error:\n{}", e.emit_to_string(src));
        });
        let info = naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("WGSL validation error:\n{}", e.emit_to_string(src)));
        (module, info)
    }

    #[test]
    fn every_stage_parses_and_validates_with_its_entry_points() {
        for (name, src, entries) in STAGES {
            let (module, _) = parse_and_validate(&stage_source(src));
            for e in entries {
                assert!(
                    module.entry_points.iter().any(|ep| ep.name == *e),
                    "stage {name} lacks entry point {e}"
                );
            }
        }
    }

    #[test]
    fn a_broken_shader_is_rejected() {
        // The validator is really run: a type error must be caught.
        let src = stage_source("fn f() -> u32 { return 1.5; }");
        let rejected = match naga::front::wgsl::parse_str(&src) {
            Err(_) => true,
            Ok(m) => naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&m)
            .is_err(),
        };
        assert!(rejected);
    }

    /// (size, [(field, offset)]) of a WGSL struct, from naga's layouter.
    fn wgsl_layout(module: &naga::Module, name: &str) -> (u32, Vec<(String, u32)>) {
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).expect("layout");
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("no struct {name}"));
        let naga::TypeInner::Struct { members, .. } = &ty.inner else {
            panic!("{name} is not a struct");
        };
        let fields = members
            .iter()
            .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
            .collect();
        (layouter[handle].size, fields)
    }

    #[test]
    fn shared_structs_have_the_same_layout_in_rust_and_wgsl() {
        let (module, _) = parse_and_validate(COMMON_WGSL);
        let check = |name: &str, size: usize, offsets: &[(&str, usize)]| {
            let (wsize, wfields) = wgsl_layout(&module, name);
            assert_eq!(wsize as usize, size, "size of {name}");
            assert_eq!(wfields.len(), offsets.len(), "field count of {name}");
            for ((wname, woff), (rname, roff)) in wfields.iter().zip(offsets) {
                assert_eq!(*woff as usize, *roff, "{name}.{wname} (Rust {rname})");
            }
        };
        check(
            "Particle",
            size_of::<Particle>(),
            &[
                ("cx", offset_of!(Particle, cx)),
                ("cy", offset_of!(Particle, cy)),
                ("a", offset_of!(Particle, a)),
                ("b", offset_of!(Particle, b)),
                ("rx", offset_of!(Particle, rx)),
                ("ry", offset_of!(Particle, ry)),
                ("rz", offset_of!(Particle, rz)),
                ("_pad", offset_of!(Particle, _pad)),
            ],
        );
        check(
            "TermLogs",
            size_of::<TermLogs>(),
            &[
                ("colour", offset_of!(TermLogs, colour)),
                ("gradient", offset_of!(TermLogs, gradient)),
                ("feature", offset_of!(TermLogs, feature)),
                ("contrast", offset_of!(TermLogs, contrast)),
                ("total", offset_of!(TermLogs, total)),
            ],
        );
        check(
            "LiftedFeature",
            size_of::<LiftedFeature>(),
            &[
                ("x", offset_of!(LiftedFeature, x)),
                ("q", offset_of!(LiftedFeature, q)),
            ],
        );
        check(
            "LikelihoodParams",
            size_of::<LikelihoodParams>(),
            &[
                ("sigma_colour", offset_of!(LikelihoodParams, sigma_colour)),
                ("sigma_z", offset_of!(LikelihoodParams, sigma_z)),
                (
                    "clutter_density",
                    offset_of!(LikelihoodParams, clutter_density),
                ),
                ("p_no_contour", offset_of!(LikelihoodParams, p_no_contour)),
                (
                    "edge_threshold",
                    offset_of!(LikelihoodParams, edge_threshold),
                ),
                (
                    "line_half_length",
                    offset_of!(LikelihoodParams, line_half_length),
                ),
                ("feature_eps", offset_of!(LikelihoodParams, feature_eps)),
                ("depth_ratio", offset_of!(LikelihoodParams, depth_ratio)),
                ("num_lines", offset_of!(LikelihoodParams, num_lines)),
                ("terms", offset_of!(LikelihoodParams, terms)),
                ("colour_bins", offset_of!(LikelihoodParams, colour_bins)),
                (
                    "contrast_scale",
                    offset_of!(LikelihoodParams, contrast_scale),
                ),
            ],
        );
        check(
            "FrameUniform",
            size_of::<FrameUniform>(),
            &[
                ("prev", offset_of!(FrameUniform, prev)),
                ("width", offset_of!(FrameUniform, width)),
                ("height", offset_of!(FrameUniform, height)),
                ("n", offset_of!(FrameUniform, n)),
                ("num_features", offset_of!(FrameUniform, num_features)),
                ("theta0", offset_of!(FrameUniform, theta0)),
                ("line_h", offset_of!(FrameUniform, line_h)),
                ("flags", offset_of!(FrameUniform, flags)),
                ("q_sum", offset_of!(FrameUniform, q_sum)),
            ],
        );
    }

    #[test]
    fn uniform_structs_are_multiples_of_16_bytes() {
        assert_eq!(size_of::<LikelihoodParams>() % 16, 0);
        assert_eq!(size_of::<FrameUniform>() % 16, 0);
    }
}
