// Feature term (twin of src/likelihood/cpu/feature.rs): one invocation per particle, looping
// over the matched features. Each feature p of the previous frame is lifted onto the
// ellipsoid prior of the previous estimate, X = (p - c_prev, z), rotated by
// dR = R_i R_prev^T (R = Rx Ry Rz), scaled by s = sqrt(a b / (a_prev b_prev)) and moved to the
// particle's centre; ln p_feature = ln(sum_j 1 / (eps + |q_j - q_hat_j|)), 0 without features.

@group(0) @binding(4) var<storage, read> particles: array<Particle>;
@group(0) @binding(6) var<storage, read> features: array<FeaturePair>;
@group(0) @binding(7) var<storage, read_write> terms: array<TermLogs>;

// R = Rx(rx) Ry(ry) Rz(rz), rows as the columns of the returned matrix's transpose:
// m[r] is row r.
fn rot_rows(rx: f32, ry: f32, rz: f32) -> array<vec3<f32>, 3> {
    let ca = cos(rx);
    let sa = sin(rx);
    let cb = cos(ry);
    let sb = sin(ry);
    let cc = cos(rz);
    let sc = sin(rz);
    return array<vec3<f32>, 3>(
        vec3<f32>(cb * cc, -cb * sc, sb),
        vec3<f32>(ca * sc + sa * sb * cc, ca * cc - sa * sb * sc, -sa * cb),
        vec3<f32>(sa * sc - ca * sb * cc, sa * cc + ca * sb * sc, ca * cb),
    );
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
    let ri = rot_rows(p.rx, p.ry, p.rz);
    let rp = rot_rows(q.rx, q.ry, q.rz);
    // dR = Ri Rp^T: entry (r, c) = row r of Ri . row c of Rp. Only rows 0 and 1 are needed.
    let d0 = vec3<f32>(dot(ri[0], rp[0]), dot(ri[0], rp[1]), dot(ri[0], rp[2]));
    let d1 = vec3<f32>(dot(ri[1], rp[0]), dot(ri[1], rp[1]), dot(ri[1], rp[2]));
    let scale = sqrt(p.a * p.b / (q.a * q.b));
    let thp = fu.theta0 + q.rz;
    let c = cos(thp);
    let s = sin(thp);
    let zs = -params.depth_ratio * sqrt(q.a * q.b);
    var sum = 0.0;
    for (var j = 0u; j < fu.num_features; j++) {
        let f = features[j];
        let dx = f.p.x - q.cx;
        let dy = f.p.y - q.cy;
        let u = (c * dx + s * dy) / q.a;
        let v = (-s * dx + c * dy) / q.b;
        let z = zs * sqrt(max(0.0, 1.0 - u * u - v * v));
        let x3 = vec3<f32>(dx, dy, z);
        let qx = p.cx + scale * dot(d0, x3);
        let qy = p.cy + scale * dot(d1, x3);
        let ex = f.q.x - qx;
        let ey = f.q.y - qy;
        sum += 1.0 / (params.feature_eps + sqrt(ex * ex + ey * ey));
    }
    terms[i].feature = log(sum);
}
