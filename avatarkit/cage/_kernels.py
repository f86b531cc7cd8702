"""Taichi kernels of the cage package (imported lazily: importing this module starts Taichi).

float64 where cancellation matters (MVC angles near a face, winding numbers); the per-frame
Gaussian rebuild runs in float32 like its inputs.
"""

from avatarkit._taichi import ensure_taichi

ti = ensure_taichi()

f64 = ti.f64
PI = 3.141592653589793
nd_f64_1 = ti.types.ndarray(dtype=ti.f64, ndim=1)
nd_f64_2 = ti.types.ndarray(dtype=ti.f64, ndim=2)
nd_f64_3 = ti.types.ndarray(dtype=ti.f64, ndim=3)
nd_f32_1 = ti.types.ndarray(dtype=ti.f32, ndim=1)
nd_f32_2 = ti.types.ndarray(dtype=ti.f32, ndim=2)
nd_i32_1 = ti.types.ndarray(dtype=ti.i32, ndim=1)
nd_i32_2 = ti.types.ndarray(dtype=ti.i32, ndim=2)


@ti.kernel
def winding(points: nd_f64_2, verts: nd_f64_2, faces: nd_i32_2, out: nd_f64_1):
    """out[p] = sum over faces of the signed solid angle / (4 pi) (Van Oosterom & Strackee)."""
    for p in range(points.shape[0]):
        x = ti.Vector([points[p, 0], points[p, 1], points[p, 2]], dt=f64)
        total = ti.f64(0.0)
        for f in range(faces.shape[0]):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            a = ti.Vector([verts[i0, 0], verts[i0, 1], verts[i0, 2]], dt=f64) - x
            b = ti.Vector([verts[i1, 0], verts[i1, 1], verts[i1, 2]], dt=f64) - x
            c = ti.Vector([verts[i2, 0], verts[i2, 1], verts[i2, 2]], dt=f64) - x
            la, lb, lc = a.norm(), b.norm(), c.norm()
            det = a.dot(b.cross(c))
            den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la
            total += ti.f64(2.0) * ti.atan2(det, den)
        out[p] = total / (ti.f64(4.0) * ti.f64(PI))


@ti.func
def _atan2_pos(y, x):
    """atan2(y, x) for y, x >= 0 in float64 without a libm call (Cephes atan: range reduction
    at tan(3 pi / 8) and 0.66, then a (4, 5) rational; ~1e-16 relative). libm's atan2 was ~40%
    of the MVC kernel's time."""
    r = ti.f64(0.0)
    t = ti.f64(0.0)
    more = ti.f64(0.0)
    if y > ti.f64(2.41421356237309504880) * x:  # angle > 3 pi / 8 (x may be 0)
        r = ti.f64(1.57079632679489661923)
        t = -x / y
        more = ti.f64(6.123233995736765886130e-17)
    elif y <= ti.f64(0.66) * x:
        t = y / x
    else:
        r = ti.f64(0.78539816339744830962)
        t = (y - x) / (y + x)
        more = ti.f64(0.5 * 6.123233995736765886130e-17)
    z = t * t
    p = (((ti.f64(-8.750608600031904122785e-1) * z + ti.f64(-1.615753718733365076637e1)) * z
          + ti.f64(-7.500855792314704667340e1)) * z + ti.f64(-1.228866684490136173410e2)) * z \
        + ti.f64(-6.485021904942025371773e1)
    q = ((((z + ti.f64(2.485846490142306297962e1)) * z + ti.f64(1.650270098316988542046e2)) * z
          + ti.f64(4.328810604912902668951e2)) * z + ti.f64(4.853903996359136964868e2)) * z \
        + ti.f64(1.945506571482613964425e2)
    return r + (t + t * (z * p / q) + more)


@ti.kernel
def atan2_pos(y: nd_f64_1, x: nd_f64_1, out: nd_f64_1):
    """Test hook for _atan2_pos."""
    for i in range(out.shape[0]):
        out[i] = _atan2_pos(y[i], x[i])


@ti.func
def _put(out: ti.template(), p, j, value, transposed: ti.i32):
    if transposed:
        out[j, p] = value
    else:
        out[p, j] = value


@ti.kernel
def mvc(points: nd_f64_2, verts: nd_f64_2, faces: nd_i32_2, face_edges: nd_i32_2, edges: nd_i32_2,
        u: nd_f64_3, theta: nd_f64_3, acc: nd_f64_2, out: nd_f32_2,
        start: ti.i32, count: ti.i32, transposed: ti.i32, eps_d: f64, eps_h: f64, eps_s: f64):
    """Mean value coordinates (Ju, Schaefer & Warren 2005) of points[start:start+count].

    Parallel over `lanes` = u.shape[0]; lane k handles points start+k, start+k+lanes, ... with
    its own scratch rows: u (lanes, C, 4) = unit vector to each vertex and 1/distance,
    theta (lanes, E, 5) = (angle, sin, cos, sin/2, cos/2) per edge (shared by its two faces),
    acc (lanes, C). out: (P, C) float32, or (C, P) when `transposed`.

    Stable forms of the paper's quantities (algebraically equal):
      theta = 2 atan2(|u_a - u_b|, |u_a + u_b|)   (2 asin(l/2) loses digits near pi, i.e. on edges;
              atan2 is the Cephes rational below, not libm's)
      s_i   = det[u0,u1,u2] / (sin th_{i+1} sin th_{i-1})   (the spherical sine rule; the paper's
              sign(det) sqrt(1 - c_i^2) cancels catastrophically near the triangle's plane)
    so w_i = (th_i - c_{i+1} th_{i-1} - c_{i-1} th_{i+1}) sin th_i / (d_i det); sin h and cos h
    come from the half angles by the addition formulas instead of sin/cos calls.
    """
    lanes = u.shape[0]
    n_v = verts.shape[0]
    n_e = edges.shape[0]
    n_f = faces.shape[0]
    for lane in range(lanes):
        p = start + lane
        while p < start + count:
            x0, x1, x2 = points[p, 0], points[p, 1], points[p, 2]
            hit = -1
            for j in range(n_v):
                d0 = verts[j, 0] - x0
                d1 = verts[j, 1] - x1
                d2 = verts[j, 2] - x2
                d = ti.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                acc[lane, j] = ti.f64(0.0)
                if d < eps_d:
                    hit = j
                else:
                    inv = ti.f64(1.0) / d
                    u[lane, j, 0] = d0 * inv
                    u[lane, j, 1] = d1 * inv
                    u[lane, j, 2] = d2 * inv
                    u[lane, j, 3] = inv
            if hit >= 0:  # on a vertex: that vertex's value
                for j in range(n_v):
                    _put(out, p, j, ti.f32(0.0), transposed)
                _put(out, p, hit, ti.f32(1.0), transposed)
            else:
                for e in range(n_e):
                    a = edges[e, 0]
                    b = edges[e, 1]
                    m0 = u[lane, a, 0] - u[lane, b, 0]
                    m1 = u[lane, a, 1] - u[lane, b, 1]
                    m2 = u[lane, a, 2] - u[lane, b, 2]
                    q0 = u[lane, a, 0] + u[lane, b, 0]
                    q1 = u[lane, a, 1] + u[lane, b, 1]
                    q2 = u[lane, a, 2] + u[lane, b, 2]
                    l2 = m0 * m0 + m1 * m1 + m2 * m2
                    s2 = q0 * q0 + q1 * q1 + q2 * q2
                    l = ti.sqrt(l2)
                    s = ti.sqrt(s2)
                    r = ti.f64(1.0) / (l2 + s2)
                    rs = ti.sqrt(r)
                    theta[lane, e, 0] = ti.f64(2.0) * _atan2_pos(l, s)
                    theta[lane, e, 1] = ti.f64(2.0) * l * s * r
                    theta[lane, e, 2] = (s2 - l2) * r
                    theta[lane, e, 3] = l * rs
                    theta[lane, e, 4] = s * rs
                planar = -1
                total = ti.f64(0.0)
                for f in range(n_f):
                    e0, e1, e2 = face_edges[f, 0], face_edges[f, 1], face_edges[f, 2]
                    t0, t1, t2 = theta[lane, e0, 0], theta[lane, e1, 0], theta[lane, e2, 0]
                    if ti.f64(PI) - ti.f64(0.5) * (t0 + t1 + t2) < eps_h:  # x lies on this triangle
                        planar = f
                        break
                    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
                    sn0, sn1, sn2 = theta[lane, e0, 1], theta[lane, e1, 1], theta[lane, e2, 1]
                    ua = ti.Vector([u[lane, i0, 0], u[lane, i0, 1], u[lane, i0, 2]], dt=f64)
                    ub = ti.Vector([u[lane, i1, 0], u[lane, i1, 1], u[lane, i1, 2]], dt=f64)
                    uc = ti.Vector([u[lane, i2, 0], u[lane, i2, 1], u[lane, i2, 2]], dt=f64)
                    det = ua.dot(ub.cross(uc))
                    p12 = sn1 * sn2
                    p20 = sn2 * sn0
                    p01 = sn0 * sn1
                    pmin = ti.min(p12, ti.min(p20, p01))
                    # |s_i| <= eps for some i: x is in the triangle's plane, outside it: no weight
                    if pmin > ti.f64(1e-300) and ti.abs(det) > eps_s * pmin:
                        cs0, cs1, cs2 = theta[lane, e0, 2], theta[lane, e1, 2], theta[lane, e2, 2]
                        # sin h, cos h for h = (t0 + t1 + t2) / 2 from the half angles
                        sa, ca = theta[lane, e0, 3], theta[lane, e0, 4]
                        sb, cb = theta[lane, e1, 3], theta[lane, e1, 4]
                        sc, cc = theta[lane, e2, 3], theta[lane, e2, 4]
                        sab = sa * cb + ca * sb
                        cab = ca * cb - sa * sb
                        sh = sab * cc + cab * sc
                        ch = cab * cc - sab * sc
                        k = ti.f64(2.0) * sh / (p12 * sn0)
                        c0 = k * (sh * cs0 - ch * sn0) * sn0 - ti.f64(1.0)
                        c1 = k * (sh * cs1 - ch * sn1) * sn1 - ti.f64(1.0)
                        c2 = k * (sh * cs2 - ch * sn2) * sn2 - ti.f64(1.0)
                        inv_det = ti.f64(1.0) / det
                        w0 = (t0 - c1 * t2 - c2 * t1) * sn0 * u[lane, i0, 3] * inv_det
                        w1 = (t1 - c2 * t0 - c0 * t2) * sn1 * u[lane, i1, 3] * inv_det
                        w2 = (t2 - c0 * t1 - c1 * t0) * sn2 * u[lane, i2, 3] * inv_det
                        acc[lane, i0] += w0
                        acc[lane, i1] += w1
                        acc[lane, i2] += w2
                        total += w0 + w1 + w2
                if planar >= 0:  # 2D barycentric coordinates inside the triangle
                    for j in range(n_v):
                        _put(out, p, j, ti.f32(0.0), transposed)
                    e0, e1, e2 = face_edges[planar, 0], face_edges[planar, 1], face_edges[planar, 2]
                    i0, i1, i2 = faces[planar, 0], faces[planar, 1], faces[planar, 2]
                    # sin(th_i) d_{i-1} d_{i+1}, scaled by 1/(d0 d1 d2): sin(th_i) / d_i
                    w0 = theta[lane, e0, 1] * u[lane, i0, 3]
                    w1 = theta[lane, e1, 1] * u[lane, i1, 3]
                    w2 = theta[lane, e2, 1] * u[lane, i2, 3]
                    ws = w0 + w1 + w2
                    _put(out, p, i0, ti.cast(w0 / ws, ti.f32), transposed)
                    _put(out, p, i1, ti.cast(w1 / ws, ti.f32), transposed)
                    _put(out, p, i2, ti.cast(w2 / ws, ti.f32), transposed)
                else:
                    inv_total = ti.f64(1.0) / total
                    for j in range(n_v):
                        _put(out, p, j, ti.cast(acc[lane, j] * inv_total, ti.f32), transposed)
            p += lanes


@ti.kernel
def principal_rebuild(xt: nd_f32_2, axis_rest: nd_f32_2, length_rest: nd_f32_1, perp: nd_f32_2,
                      offset: nd_f32_2, quat_rest: nd_f32_2, scale_rest: nd_f32_2, axis_index: nd_i32_1,
                      means: nd_f32_2, quats: nd_f32_2, scales: nd_f32_2):
    """Principal-axis rebuild (paper sec. 3.3) from deformed endpoints xt (3, 2N): columns
    [0, N) the + ends, [N, 2N) the - ends. See deform.principal_rebuild_reference."""
    n = means.shape[0]
    for i in range(n):
        xp = ti.Vector([xt[0, i], xt[1, i], xt[2, i]])
        xm = ti.Vector([xt[0, n + i], xt[1, n + i], xt[2, n + i]])
        mid = ti.f32(0.5) * (xp + xm)
        for k in ti.static(range(3)):
            means[i, k] = mid[k] + offset[i, k]
        v = xp - xm
        length = v.norm()
        a = ti.Vector([axis_rest[i, 0], axis_rest[i, 1], axis_rest[i, 2]])
        b = a
        if length > ti.f32(1e-30):
            b = v / length
        dot = a.dot(b)
        cr = a.cross(b)
        qw = ti.f32(1.0) + dot
        qv = cr
        if qw < ti.f32(1e-6):  # axis reversed: half turn about an axis perpendicular to it
            qw = ti.f32(0.0)
            qv = ti.Vector([perp[i, 0], perp[i, 1], perp[i, 2]])
        qn = ti.sqrt(qw * qw + qv.dot(qv))
        qw /= qn
        qv /= qn
        rw, rx, ry, rz = quat_rest[i, 0], quat_rest[i, 1], quat_rest[i, 2], quat_rest[i, 3]
        ow = qw * rw - qv[0] * rx - qv[1] * ry - qv[2] * rz
        ox = qw * rx + qv[0] * rw + qv[1] * rz - qv[2] * ry
        oy = qw * ry - qv[0] * rz + qv[1] * rw + qv[2] * rx
        oz = qw * rz + qv[0] * ry - qv[1] * rx + qv[2] * rw
        on = ti.sqrt(ow * ow + ox * ox + oy * oy + oz * oz)
        quats[i, 0] = ow / on
        quats[i, 1] = ox / on
        quats[i, 2] = oy / on
        quats[i, 3] = oz / on
        ratio = ti.max(length / length_rest[i], ti.f32(1e-6))
        k = axis_index[i]
        for c in ti.static(range(3)):
            s = scale_rest[i, c]
            if c == k:
                s *= ratio
            scales[i, c] = s
