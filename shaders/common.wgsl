// Shared declarations of every likelihood stage (prepended to each stage's source).
// Each struct mirrors a Rust `#[repr(C)]` Pod struct of `pftrack::likelihood`; a unit test
// compares sizes and field offsets (naga's layouter against `offset_of!`).

// `likelihood::Particle`: the state (cx, cy, a, b, rx, ry, rz), 32 bytes.
struct Particle {
    cx: f32,
    cy: f32,
    a: f32,
    b: f32,
    rx: f32,
    ry: f32,
    rz: f32,
    pad: f32,
}

// `likelihood::TermLogs`: ln of each term and their sum.
struct TermLogs {
    colour: f32,
    gradient: f32,
    feature: f32,
    contrast: f32,
    total: f32,
}

// `likelihood::LiftedFeature`: a match, its frame t-1 position lifted on the host,
// x = (p - c_prev, z), and its frame t position q. 20 bytes (arrays of f32, no vec padding).
struct LiftedFeature {
    x: array<f32, 3>,
    q: array<f32, 2>,
}

// `likelihood::LikelihoodParams`.
struct LikelihoodParams {
    sigma_colour: f32,
    sigma_z: f32,
    clutter_density: f32,
    p_no_contour: f32,
    edge_threshold: f32,
    line_half_length: f32,
    feature_eps: f32,
    depth_ratio: f32,
    num_lines: u32,
    terms: u32,
    colour_bins: u32,
    contrast_scale: f32,
}

// `likelihood::gpu::FrameUniform`: what a frame adds to the constant parameters.
struct FrameUniform {
    prev: Particle,
    width: u32,
    height: u32,
    n: u32,
    num_features: u32,
    theta0: f32,
    line_h: i32,
    flags: u32,
    q_sum: f32,
}

const TERM_COLOUR: u32 = 1u;
const TERM_GRADIENT: u32 = 2u;
const TERM_FEATURE: u32 = 4u;
const TERM_CONTRAST: u32 = 8u;
// FrameUniform::flags: write each particle's histogram counts to `hist_debug`.
const FLAG_DEBUG_HIST: u32 = 1u;
// `likelihood::DEGENERATE`.
const DEGENERATE: f32 = -1e30;
// Line distance written for a line without an edge / for a skipped particle.
const NO_EDGE: i32 = -1;
const SKIPPED: i32 = -2;

@group(0) @binding(0) var<uniform> params: LikelihoodParams;
@group(0) @binding(1) var<uniform> fu: FrameUniform;
// Per particle (sin, cos) of theta = theta0 + rz, computed on the host with Rust's f32
// `sin_cos` exactly as the CPU twin: WGSL's sin/cos differ by a few ulp, which is enough to
// move a pixel centre across an ellipse's boundary and break the exact histogram agreement.
// After the n particles' entries, the (sin, cos) of each normal line's angle phi_k, from the
// same host function as the CPU's lines: WGSL promises sin and cos only to 2^-11 (and nothing
// past pi), and on an axis-aligned ellipse with a half-pixel centre cos(pi/2) = -4.4e-8
// against 0 moved a whole line to the next column.
@group(0) @binding(10) var<storage, read> trig: array<vec2<f32>>;

// Whether a float is NaN or infinite, from its bits (immune to fast-math folding of x != x).
fn non_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) == 0x7f800000u;
}

// A degenerate particle: a <= 0, b <= 0 or any component non-finite (`likelihood::DEGENERATE`).
fn is_degenerate(p: Particle) -> bool {
    let bad = non_finite(p.cx) || non_finite(p.cy) || non_finite(p.a) || non_finite(p.b)
        || non_finite(p.rx) || non_finite(p.ry) || non_finite(p.rz);
    return bad || !(p.a > 0.0) || !(p.b > 0.0);
}

// Flat index of a workgroup in a (possibly 2D) dispatch: more than 65535 workgroups are laid
// out as rows of `nwg.x`.
fn flat_group(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}
