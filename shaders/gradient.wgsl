// Gradient term (twin of src/likelihood/cpu/gradient.rs), two kernels.
//
// `gradient_image`: one invocation per pixel, exact integer arithmetic:
//   L = 299 r + 587 g + 114 b, gx = L(x+1,y) - L(x-1,y), gy = L(x,y+1) - L(x,y-1), indices
//   clamped to the frame; stored as a pair of i32.
// `gradient_lines`: one invocation per (particle, normal line). Walks t = -H..=H along the
//   outward normal at phi_k = 2 pi k / L, keeps the edges (local maxima of the normal gradient
//   strength above the threshold) and writes the smallest |t| of an edge (NO_EDGE when none)
//   to `line_d`. The combine kernel turns the distances into ln p_gradient.

@group(0) @binding(2) var<storage, read> pixels: array<u32>;
@group(0) @binding(3) var<storage, read_write> grad: array<vec2<i32>>;
@group(0) @binding(4) var<storage, read> particles: array<Particle>;
@group(0) @binding(8) var<storage, read_write> line_d: array<i32>;

fn luma_at(x: u32, y: u32) -> i32 {
    let px = pixels[y * fu.width + x];
    let r = px & 0xffu;
    let g = (px >> 8u) & 0xffu;
    let b = (px >> 16u) & 0xffu;
    return i32(299u * r + 587u * g + 114u * b);
}

@compute @workgroup_size(16, 16)
fn gradient_image(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    let y = gid.y;
    if x >= fu.width || y >= fu.height {
        return;
    }
    let xl = select(x - 1u, 0u, x == 0u);
    let xr = min(x + 1u, fu.width - 1u);
    let yu = select(y - 1u, 0u, y == 0u);
    let yd = min(y + 1u, fu.height - 1u);
    let gx = luma_at(xr, y) - luma_at(xl, y);
    let gy = luma_at(x, yd) - luma_at(x, yu);
    grad[y * fu.width + x] = vec2<i32>(gx, gy);
}

// Normal gradient strength (luma units per pixel) at sample t of a line; 0 outside the frame.
fn strength(lx: f32, ly: f32, nx: f32, ny: f32, t: i32) -> f32 {
    let ft = f32(t);
    let fx = floor(lx + ft * nx + 0.5);
    let fy = floor(ly + ft * ny + 0.5);
    if !(fx >= 0.0 && fx < f32(fu.width) && fy >= 0.0 && fy < f32(fu.height)) {
        return 0.0;
    }
    let g = grad[u32(fy) * fu.width + u32(fx)];
    return abs(f32(g.x) * nx + f32(g.y) * ny) / (2.0 * 255000.0);
}

@compute @workgroup_size(64)
fn gradient_lines(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let nl = params.num_lines;
    let idx = flat_group(wid, nwg) * 64u + lid;
    if nl == 0u || idx >= fu.n * nl {
        return;
    }
    let i = idx / nl;
    let k = idx % nl;
    let p = particles[i];
    if is_degenerate(p) {
        line_d[idx] = SKIPPED;
        return;
    }
    let sc = trig[i];
    let s = sc.x;
    let c = sc.y;
    let line = trig[fu.n + k];
    let sp = line.x;
    let cp = line.y;
    // Contour point (geometry::Ellipse::point_at).
    let ex = p.a * cp;
    let ey = p.b * sp;
    let lx = p.cx + c * ex - s * ey;
    let ly = p.cy + s * ex + c * ey;
    // Outward unit normal (geometry::Ellipse::normal_at).
    let n0x = cp / p.a;
    let n0y = sp / p.b;
    let nn = sqrt(n0x * n0x + n0y * n0y);
    let ux = n0x / nn;
    let uy = n0y / nn;
    let nx = c * ux - s * uy;
    let ny = s * ux + c * uy;

    let h = fu.line_h;
    let thr = params.edge_threshold;
    var best = NO_EDGE;
    var g_prev = 0.0;
    var g_cur = strength(lx, ly, nx, ny, -h);
    for (var t = -h; t <= h; t++) {
        var g_next = 0.0;
        if t < h {
            g_next = strength(lx, ly, nx, ny, t + 1);
        }
        if g_cur >= thr && g_cur > g_prev && g_cur >= g_next {
            let d = abs(t);
            if best < 0 || d < best {
                best = d;
            }
        }
        g_prev = g_cur;
        g_cur = g_next;
    }
    line_d[idx] = best;
}
