// Feature term (twin of src/likelihood/cpu/feature.rs): one invocation per particle, looping
// over the matched features. Each feature p of the previous frame comes lifted to 3D by the
// host (the same lift as the CPU twin's), X = (p - c_prev, z); it is rotated by
// dR = R_i R_prev^T (R = Rx Ry Rz), scaled by s = sqrt(a b / (a_prev b_prev)) and moved to the
// particle's centre; ln p_feature = ln(sum_j 1 / (eps + |q_j - q_hat_j|)), 0 without features.

@group(0) @binding(4) var<storage, read> particles: array<Particle>;
@group(0) @binding(6) var<storage, read> features: array<LiftedFeature>;
@group(0) @binding(7) var<storage, read_write> terms: array<TermLogs>;

// 3x3 matrices as arrays of rows; the products are written out term by term, each entry
// summed as (a0 b0 + a1 b1) + a2 b2, the order of the CPU twin's glam products, so only
// sin/cos differ between the two.
fn mat_mul(a: array<vec3<f32>, 3>, b: array<vec3<f32>, 3>) -> array<vec3<f32>, 3> {
    var m: array<vec3<f32>, 3>;
    for (var i = 0; i < 3; i++) {
        let r = a[i];
        m[i] = vec3<f32>(
            r.x * b[0].x + r.y * b[1].x + r.z * b[2].x,
            r.x * b[0].y + r.y * b[1].y + r.z * b[2].y,
            r.x * b[0].z + r.y * b[1].z + r.z * b[2].z,
        );
    }
    return m;
}

fn transpose3(a: array<vec3<f32>, 3>) -> array<vec3<f32>, 3> {
    return array<vec3<f32>, 3>(
        vec3<f32>(a[0].x, a[1].x, a[2].x),
        vec3<f32>(a[0].y, a[1].y, a[2].y),
        vec3<f32>(a[0].z, a[1].z, a[2].z),
    );
}

// The angle moved into [-pi, pi], where WGSL bounds sin's and cos's error (it promises
// nothing past it); angles already there, as the tracker's are, pass unchanged.
fn wrap_pi(x: f32) -> f32 {
    let turn = 6.2831855;
    return x - turn * round(x / turn);
}

// R = Rx(rx) Ry(ry) Rz(rz) (SPEC), as rows.
fn rotation(rx: f32, ry: f32, rz: f32) -> array<vec3<f32>, 3> {
    let sa = sin(wrap_pi(rx));
    let ca = cos(wrap_pi(rx));
    let sb = sin(wrap_pi(ry));
    let cb = cos(wrap_pi(ry));
    let sc = sin(wrap_pi(rz));
    let cc = cos(wrap_pi(rz));
    let mx = array<vec3<f32>, 3>(vec3(1.0, 0.0, 0.0), vec3(0.0, ca, -sa), vec3(0.0, sa, ca));
    let my = array<vec3<f32>, 3>(vec3(cb, 0.0, sb), vec3(0.0, 1.0, 0.0), vec3(-sb, 0.0, cb));
    let mz = array<vec3<f32>, 3>(vec3(cc, -sc, 0.0), vec3(sc, cc, 0.0), vec3(0.0, 0.0, 1.0));
    return mat_mul(mat_mul(mx, my), mz);
}

@compute @workgroup_size(64)
fn feature(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    let i = flat_group(wid, nwg) * 64u + lid;
    if i >= fu.n {
        return;
    }
    let p = particles[i];
    if is_degenerate(p) || fu.num_features == 0u {
        terms[i].feature = 0.0;
        return;
    }
    let q = fu.prev;
    let dr = mat_mul(rotation(p.rx, p.ry, p.rz), transpose3(rotation(q.rx, q.ry, q.rz)));
    let d0 = dr[0];
    let d1 = dr[1];
    let scale = sqrt((p.a * p.b) / (q.a * q.b));
    var sum = 0.0;
    for (var j = 0u; j < fu.num_features; j++) {
        let f = features[j];
        let dx = f.x[0];
        let dy = f.x[1];
        let z = f.x[2];
        let qx = p.cx + scale * (d0.x * dx + d0.y * dy + d0.z * z);
        let qy = p.cy + scale * (d1.x * dx + d1.y * dy + d1.z * z);
        let ex = f.q[0] - qx;
        let ey = f.q[1] - qy;
        sum += 1.0 / (params.feature_eps + sqrt(ex * ex + ey * ey));
    }
    terms[i].feature = log(sum);
}
