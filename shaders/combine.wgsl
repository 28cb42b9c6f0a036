// Combination (twin of src/likelihood/cpu/combine.rs): one invocation per particle.
// ln p_gradient = sum over lines (in line order) of ln(1 + K exp(-d^2 / (2 sigma_z^2))),
// K = 1 / (sqrt(2 pi) sigma_z p0 gamma), 0 for a line without an edge; total = the sum of the
// enabled terms (colour + gradient + feature + contrast), a disabled term is 0; a degenerate particle
// gets 0 for each term and total = DEGENERATE, and so does a particle whose total is not
// finite.

@group(0) @binding(4) var<storage, read> particles: array<Particle>;
@group(0) @binding(7) var<storage, read_write> terms: array<TermLogs>;
@group(0) @binding(8) var<storage, read_write> line_d: array<i32>;

@compute @workgroup_size(64)
fn combine(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_group(wid, nwg) * 64u + lid;
    if i >= fu.n {
        return;
    }
    if is_degenerate(particles[i]) {
        terms[i] = TermLogs(0.0, 0.0, 0.0, 0.0, DEGENERATE);
        return;
    }
    var out = TermLogs(0.0, 0.0, 0.0, 0.0, 0.0);
    if (params.terms & TERM_COLOUR) != 0u {
        out.colour = terms[i].colour;
    }
    if (params.terms & TERM_GRADIENT) != 0u {
        let sz = params.sigma_z;
        let k = 1.0 / (2.5066283 * sz * params.p_no_contour * params.clutter_density);
        let nl = params.num_lines;
        var g = 0.0;
        for (var l = 0u; l < nl; l++) {
            let d = line_d[i * nl + l];
            if d >= 0 {
                let fd = f32(d);
                g += log(1.0 + k * exp(-(fd * fd) / (2.0 * sz * sz)));
            }
        }
        out.gradient = g;
    }
    // Without features the feature kernel does not run (its slot holds the previous frame's
    // value): the term is 0, as on the CPU.
    if (params.terms & TERM_FEATURE) != 0u && fu.num_features > 0u {
        out.feature = terms[i].feature;
    }
    if (params.terms & TERM_CONTRAST) != 0u {
        out.contrast = terms[i].contrast;
    }
    out.total = out.colour + out.gradient + out.feature + out.contrast;
    // Non-finite results never escape (as on the CPU).
    if non_finite(out.total) {
        out = TermLogs(0.0, 0.0, 0.0, 0.0, DEGENERATE);
    }
    terms[i] = out;
}
