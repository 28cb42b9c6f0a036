// Colour term (twin of src/likelihood/cpu/colour.rs): one workgroup per particle.
// The 8x8x8 RGB histogram (or with params.colour_bins == 1, for grayscale footage, the 64
// luma levels (77 r + 150 g + 29 b + 128) >> 8 >> 2 in the same 512 bins) of the pixel
// centres inside the particle's ellipse is built in
// workgroup memory with atomics (exact integer counts), then reduced in the same workgroup to
// the Bhattacharyya coefficient against the model, rho = sum_k sqrt(p_k q_k), and
// ln p_colour = -(1 - rho) / (2 sigma_c^2). As on the CPU, rho is divided by
// sqrt(sum_k p_k * sum_k q_k) (1 in exact arithmetic; it cancels the rounding of the two
// normalisations, so a histogram against itself gives exactly 1) and clamped to at most 1;
// total == 0 or an empty model gives rho = 0. q_sum (bin order, f32) comes from the host.
// The same histogram gives the contrast term: params.contrast_scale * sum_k count_k L_k, with
// the contrast table L in model[512..1024] (the sum's order differs from the CPU's bin order,
// so the two agree to f32 rounding, not bit for bit).

@group(0) @binding(2) var<storage, read> pixels: array<u32>;
@group(0) @binding(4) var<storage, read> particles: array<Particle>;
@group(0) @binding(5) var<storage, read> model: array<f32>;
@group(0) @binding(7) var<storage, read_write> terms: array<TermLogs>;
@group(0) @binding(9) var<storage, read_write> hist_debug: array<u32>;

const WG: u32 = 64u;
const BINS: u32 = 512u;
const BINS_PER_THREAD: u32 = 8u; // BINS / WG

var<workgroup> hist: array<atomic<u32>, 512>;
var<workgroup> red_u: array<u32, 64>;
var<workgroup> red_f: array<f32, 64>;
var<workgroup> red_p: array<f32, 64>;
var<workgroup> red_l: array<f32, 64>;

@compute @workgroup_size(64)
fn colour(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_group(wid, nwg);
    // Uniform across the workgroup, so every barrier below is reached by all invocations,
    // and a spare group of the grid's last row leaves at once.
    let in_range = i < fu.n;
    if !in_range {
        return;
    }
    for (var k = lid; k < BINS; k += WG) {
        atomicStore(&hist[k], 0u);
    }
    workgroupBarrier();

    var p = Particle();
    var ok = false;
    if in_range {
        p = particles[i];
        ok = !is_degenerate(p);
    }
    if ok {
        let sc = trig[i];
        let s = sc.x;
        let c = sc.y;
        // Bounding box of the rotated ellipse, one pixel generous (the inside test decides),
        // clamped to the frame in f32 before any integer conversion.
        let hw = sqrt((p.a * c) * (p.a * c) + (p.b * s) * (p.b * s));
        let hh = sqrt((p.a * s) * (p.a * s) + (p.b * c) * (p.b * c));
        let wmax = f32(fu.width) - 1.0;
        let hmax = f32(fu.height) - 1.0;
        let fx0 = clamp(ceil(p.cx - hw) - 1.0, 0.0, wmax);
        let fx1 = clamp(floor(p.cx + hw) + 1.0, 0.0, wmax);
        let fy0 = clamp(ceil(p.cy - hh) - 1.0, 0.0, hmax);
        let fy1 = clamp(floor(p.cy + hh) + 1.0, 0.0, hmax);
        // Box fully left/right/above/below the frame: empty. With the box's pixel of slack:
        // an ellipse touching the frame's first pixel centre from outside (cx = -a) counts
        // it on the CPU, and a sqrt a ulp low here would have called it empty.
        let empty = p.cx + hw < -1.0 || p.cx - hw > wmax + 1.0 || p.cy + hh < -1.0
            || p.cy - hh > hmax + 1.0;
        if !empty {
            let x0 = u32(fx0);
            let y0 = u32(fy0);
            let bw = u32(fx1) - x0 + 1u;
            let bh = u32(fy1) - y0 + 1u;
            let count = bw * bh;
            for (var j = lid; j < count; j += WG) {
                let x = x0 + j % bw;
                let y = y0 + j / bw;
                let dx = f32(x) - p.cx;
                let dy = f32(y) - p.cy;
                let u = (c * dx + s * dy) / p.a;
                let v = (-s * dx + c * dy) / p.b;
                if u * u + v * v <= 1.0 {
                    let px = pixels[y * fu.width + x];
                    let r = px & 0xffu;
                    let g = (px >> 8u) & 0xffu;
                    let b = (px >> 16u) & 0xffu;
                    var bin = (r >> 5u) * 64u + (g >> 5u) * 8u + (b >> 5u);
                    if params.colour_bins == 1u {
                        bin = ((77u * r + 150u * g + 29u * b + 128u) >> 8u) >> 2u;
                    }
                    atomicAdd(&hist[bin], 1u);
                }
            }
        }
    }
    workgroupBarrier();

    // Total pixel count: each invocation sums its 8 bins, then a tree reduction.
    let k0 = lid * BINS_PER_THREAD;
    var cnt = 0u;
    for (var k = 0u; k < BINS_PER_THREAD; k++) {
        cnt += atomicLoad(&hist[k0 + k]);
    }
    red_u[lid] = cnt;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            red_u[lid] += red_u[lid + stride];
        }
        workgroupBarrier();
    }
    let total = red_u[0];

    // rho = sum_k sqrt(p_k q_k), p_k = count_k / total, and the contrast sum; with
    // total == 0 every count is 0 and all three sums stay 0.
    var acc = 0.0;
    var psum = 0.0;
    var lsum = 0.0;
    if total > 0u {
        let tf = f32(total);
        for (var k = 0u; k < BINS_PER_THREAD; k++) {
            let cnt_k = atomicLoad(&hist[k0 + k]);
            if cnt_k != 0u {
                let pk = f32(cnt_k) / tf;
                acc += sqrt(pk * model[k0 + k]);
                psum += pk;
                lsum += f32(cnt_k) * model[BINS + k0 + k];
            }
        }
    }
    red_f[lid] = acc;
    red_p[lid] = psum;
    red_l[lid] = lsum;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride /= 2u) {
        if lid < stride {
            red_f[lid] += red_f[lid + stride];
            red_p[lid] += red_p[lid + stride];
            red_l[lid] += red_l[lid + stride];
        }
        workgroupBarrier();
    }

    if in_range {
        if (fu.flags & FLAG_DEBUG_HIST) != 0u {
            for (var k = 0u; k < BINS_PER_THREAD; k++) {
                hist_debug[i * BINS + k0 + k] = atomicLoad(&hist[k0 + k]);
            }
        }
        if lid == 0u {
            var rho = 0.0;
            if total > 0u && fu.q_sum > 0.0 {
                rho = min(red_f[0] / sqrt(red_p[0] * fu.q_sum), 1.0);
            }
            let sc = params.sigma_colour;
            terms[i].colour = -(1.0 - rho) / (2.0 * sc * sc);
            terms[i].contrast = params.contrast_scale * red_l[0];
        }
    }
}
