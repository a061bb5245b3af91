// The sweep method's horizons (src/horizon/linesweep.rs) on the GPU: the same lines, hulls,
// near field and edge scans, in f32 with each line's points in a frame of its own so that no
// absolute position on the body is held in f32 (docs/horizons.md, "On the GPU").
//
// Two passes per batch of azimuth jobs (a job is φ, or φ and φ + π sharing the lines):
//   `lines`:  one invocation per line q = m + t·p: samples it where it crosses the columns,
//             sweeps it from each end keeping the upper convex hull as a persistent chain, and
//             gives each pixel it brackets the slope of the vertex that pixel sees highest
//             (into `far`, one slot per bracketing line: each slot has one writer).
//   `pixels`: one invocation per pixel and direction: the near field on its own ray, the two
//             lines' slopes weighted by nearness, the zero-distance slope, degrees.
//
// No data is one NaN bit pattern (the host makes every NaN that one), tested by its bits:
// nothing here relies on NaN arithmetic, which WGSL leaves to the implementation.

const NONE: u32 = 0xffffffffu;
const NODATA: u32 = 0x7fc00000u;
const NEG: f32 = -3.0e38;
const BIG: f32 = 3.0e38;
// Set by the host from the library's values (one source: `horizon::device`): the columns next
// to each pixel searched on its own ray, how near the raster's edge must be for the edge scan,
// and the near-field steps per direction the steps buffer has room for.
override NEAR_COLS: i32;
override EDGE_SCAN: f32;
override MAX_STEPS: u32;
const DEG: f32 = 57.29577951308232;

struct Params {
    width: u32,
    height: u32,
    rx0: u32,
    ry0: u32,
    rw: u32,
    rh: u32,
    jobs: u32,
    max_lines: u32,
    // The raster origin's face pixel (exact in f32 below 2^24), face pixels S, radius (m).
    ox: f32,
    oy: f32,
    face_px: f32,
    radius: f32,
    np_max: u32,
    // Invocations per row of the pixel pass's dispatch.
    row_threads: u32,
    // Observer columns per invocation of the `observers` pass.
    seg: u32,
}

struct Job {
    xmajor: u32,
    look: i32,
    step: i32,
    dirs: u32,
    t: f32,
    m_lo: i32,
    m_hi: i32,
    pc: i32,
    rp0: i32,
    rp1: i32,
    rq0: i32,
    rq1: i32,
    du: f32,
    dv: f32,
    adp: f32,
    nsteps0: u32,
    nsteps1: u32,
    _pad0: u32,
    zp0: i32,
    zwp0: f32,
    zq0: i32,
    zwq0: f32,
    zp1: i32,
    zwp1: f32,
    zq1: i32,
    zwq1: f32,
}

struct Step {
    k: f32,
    four: u32,
    _a: u32,
    _b: u32,
    dc: vec4<i32>,
    dr: vec4<i32>,
    w: vec4<f32>,
}

struct Sample {
    x: f32,
    y: f32,
    // The hull's chain and top, per direction.
    pred0: u32,
    pred1: u32,
    top0: u32,
    top1: u32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> heights: array<f32>;
@group(0) @binding(2) var<storage, read> jobs: array<Job>;
@group(0) @binding(3) var<storage, read> steps: array<Step>;
@group(0) @binding(4) var<storage, read> cols: array<vec2<f32>>;
@group(0) @binding(5) var<storage, read_write> scratch: array<Sample>;
@group(0) @binding(6) var<storage, read_write> far: array<u32>;
@group(0) @binding(7) var<storage, read_write> outp: array<f32>;

fn valid(h: f32) -> bool {
    return bitcast<u32>(h) != NODATA;
}

fn nodata() -> f32 {
    return bitcast<f32>(NODATA);
}

// Height at (p, q) of the raster read in (major, minor) order.
fn g(xm: bool, p: i32, q: i32) -> f32 {
    if xm {
        return heights[u32(q) * P.width + u32(p)];
    }
    return heights[u32(p) * P.width + u32(q)];
}

// a + w·(b − a) on a grid line, a no-data tap left out; no data where both are.
fn on_grid_line(a: f32, b: f32, w: f32) -> f32 {
    let va = valid(a);
    let vb = valid(b);
    if va && vb {
        return a + w * (b - a);
    }
    if va {
        return a;
    }
    return b;
}

// Bilinear height on column p at minor coordinate qi + f (0 ≤ f < 1); no data off the raster.
fn on_col(xm: bool, p: i32, qi: i32, f: f32, nq: i32) -> f32 {
    if qi < 0 || qi > nq - 1 {
        return nodata();
    }
    if f == 0.0 {
        return g(xm, p, qi);
    }
    if qi + 1 > nq - 1 {
        return nodata();
    }
    return on_grid_line(g(xm, p, qi), g(xm, p, qi + 1), f);
}

// Gnomonic (u, v, 1) of raster position (p, q).
fn plane_point(xm: bool, p: f32, q: f32) -> vec3<f32> {
    var x = q;
    var y = p;
    if xm {
        x = p;
        y = q;
    }
    let s = P.face_px;
    return vec3<f32>((2.0 * (P.ox + x) + 1.0 - s) / s, (s - 2.0 * (P.oy + y) - 1.0) / s, 1.0);
}

// The ray geometry of pixel (p, q) for the look direction: tan γ_k = kα/(1 + kβ).
fn pixel_ab(j: Job, xm: bool, p: i32, q: i32) -> vec2<f32> {
    let x = plane_point(xm, f32(p), f32(q));
    let d = f32(j.look) * vec3<f32>(j.du, j.dv, 0.0);
    let n2 = dot(x, x);
    return vec2<f32>(length(cross(x, d)) / n2, dot(x, d) / n2);
}

fn col(jn: u32, p: i32) -> vec2<f32> {
    return cols[jn * P.np_max + u32(p)];
}

// ---------------------------------------------------------------------------------------------
// Lines.

struct Line {
    jn: u32,
    m: i32,
    xm: bool,
    np: i32,
    nq: i32,
    base: u32,
    al: f32,
    be: f32,
    // The columns where the line runs within a pixel of the raster.
    pa: i32,
    pb: i32,
}

// Line `li` of job `jn` (q = m + t·p, m = m_lo + li): its frame and span; `ok` false where it
// brackets no observer (nothing to do).
struct LineSetup {
    ok: bool,
    l: Line,
}

fn line_setup(jn: u32, li: u32) -> LineSetup {
    var r: LineSetup;
    r.ok = false;
    if jn >= P.jobs || li >= P.max_lines {
        return r;
    }
    let j = jobs[jn];
    let m = j.m_lo + i32(li);
    if m > j.m_hi {
        return r;
    }
    let xm = j.xmajor != 0u;
    let np = select(i32(P.height), i32(P.width), xm);
    let nq = select(i32(P.width), i32(P.height), xm);
    let t = j.t;
    let mf = f32(m);
    var pa = 0;
    var pb = np - 1;
    if t != 0.0 {
        let e0 = clamp((-1.0 - mf) / t, -1e9, 1e9);
        let e1 = clamp((f32(nq) - mf) / t, -1e9, 1e9);
        pa = max(pa, i32(floor(min(e0, e1))));
        pb = min(pb, i32(ceil(max(e0, e1))));
    } else if mf < -1.0 || mf > f32(nq) {
        return r;
    }
    if pa > pb {
        return r;
    }
    let ylo = mf + t * f32(j.rp0);
    let yhi = mf + t * f32(j.rp1 - 1);
    if max(ylo, yhi) <= f32(j.rq0 - 1) || min(ylo, yhi) >= f32(j.rq1) {
        return r;
    }
    // The line's frame: angles from its point at the reference column, in its plane.
    let cpc = col(jn, j.pc);
    let xc = plane_point(xm, f32(j.pc), mf + cpc.x + cpc.y);
    let b = f32(j.step) * vec3<f32>(j.du, j.dv, 0.0);
    let n2 = dot(xc, xc);
    r.ok = true;
    r.l.jn = jn;
    r.l.m = m;
    r.l.xm = xm;
    r.l.np = np;
    r.l.nq = nq;
    r.l.base = (jn * P.max_lines + li) * P.np_max;
    r.l.al = length(cross(xc, b)) / n2;
    r.l.be = dot(xc, b) / n2;
    r.l.pa = pa;
    r.l.pb = pb;
    return r;
}

// The line's height at column p: where it crosses the column (exact bilinear), or no data.
fn line_height(l: Line, p: i32) -> f32 {
    let c = col(l.jn, p);
    return on_col(l.xm, p, l.m + i32(c.x), c.y, l.nq);
}

// The direction of the line's point at column p, as (sin, cos) of the angle at the body
// centre from its point at the reference column, growing along the sweep of direction 0: from
// tan = dα/(1 + dβ) by a root, not by trigonometry (whose accuracy a GPU need not keep for
// small angles).
fn dir_at(l: Line, j: Job, p: i32) -> vec2<f32> {
    let d = f32((p - j.pc) * j.step);
    let v = vec2<f32>(d * l.al, 1.0 + d * l.be);
    return v / length(v);
}

// A point `h` above the sphere in the direction `u` = (sin, cos), in the line's frame (the
// origin on the sphere at the reference column): ((R + h)·sin, h − (R + h)·(1 − cos)), with
// 1 − cos = sin²/(1 + cos) (no cancellation).
fn place(u: vec2<f32>, h: f32) -> vec2<f32> {
    let rh = P.radius + h;
    return vec2<f32>(rh * u.x, h - rh * u.x * u.x / (1.0 + u.y));
}

fn pred_of(i: u32, dir: u32) -> u32 {
    return select(scratch[i].pred1, scratch[i].pred0, dir == 0u);
}

// (b − a) × (c − a) of samples a, b, c (x mirrored by `mi`): ≥ 0 where b lies on or below the
// chord a–c.
fn cross3(mi: f32, a: u32, b: u32, c: u32) -> f32 {
    let sa = scratch[a];
    let sb = scratch[b];
    let sc = scratch[c];
    let ax = mi * sa.x;
    return (mi * sb.x - ax) * (sc.y - sa.y) - (sb.y - sa.y) * (mi * sc.x - ax);
}

// An observer on the line in direction u, h0 above the sphere, in the line's frame (x
// mirrored by `mi`).
fn observer(mi: f32, u: vec2<f32>, h0: f32) -> vec2<f32> {
    let o = place(u, h0);
    return vec2<f32>(mi * o.x, o.y);
}

// The hull vertex (a column) that observer `o` sees highest, walking direction `dir`'s chain
// from `from_v` (the elevation is unimodal along a convex chain seen from outside it).
fn walk(l: Line, dir: u32, mi: f32, o: vec2<f32>, from_v: u32) -> u32 {
    let s0 = scratch[l.base + from_v];
    var best = vec2<f32>(mi * s0.x - o.x, s0.y - o.y);
    var bi = from_v;
    var v = pred_of(l.base + from_v, dir);
    loop {
        if v == NONE {
            break;
        }
        let sv = scratch[l.base + v];
        let c = vec2<f32>(mi * sv.x - o.x, sv.y - o.y);
        if best.x * c.y - best.y * c.x < 0.0 {
            best = c;
            bi = v;
            v = pred_of(l.base + v, dir);
        } else {
            break;
        }
    }
    return bi;
}

// The slope (tan of elevation) of vertex v from observer `o` in direction u; NEG where it does
// not lie ahead.
fn slope(l: Line, mi: f32, o: vec2<f32>, u: vec2<f32>, v: u32) -> f32 {
    let ux = mi * u.x;
    let uy = u.y;
    let sv = scratch[l.base + v];
    let dx = mi * sv.x - o.x;
    let dy = sv.y - o.y;
    let up = dx * ux + dy * uy;
    let hor = -dx * uy + dy * ux;
    if hor > 0.0 {
        return up / hor;
    }
    return NEG;
}

// The slope of terrain hk, k columns out on a ray with geometry (alpha, beta), from an observer
// h0 above the sphere: tan γ = kα/(1 + kβ), the curvature drop (R + h0)·(sec γ − 1).
fn ray_slope(k: f32, alpha: f32, beta: f32, h0: f32, hk: f32) -> f32 {
    let r = P.radius;
    let tt = k * alpha / (1.0 + k * beta);
    let q2 = tt * tt;
    let drop = (r + h0) * q2 / (1.0 + sqrt(1.0 + q2));
    return ((hk - h0) - drop) / ((r + hk) * tt);
}

// The best slope on pixel (p, q)'s own ray (direction s along p) where it crosses columns and
// rows between kf and kt columns out: the rays near the raster's edge that the lines cannot
// serve.
fn scan(jn: u32, j: Job, xm: bool, np: i32, nq: i32, p: i32, q: i32, s: i32, kf: f32, kt: f32,
        alpha: f32, beta: f32) -> f32 {
    let h0 = g(xm, p, q);
    var best = NEG;
    var k = max(ceil(kf), 1.0);
    let cp = col(jn, p);
    loop {
        if k > kt {
            break;
        }
        let pc = p + s * i32(k);
        if pc >= 0 && pc < np {
            let cc = col(jn, pc);
            var qi = q + i32(cc.x - cp.x);
            var f = cc.y - cp.y;
            if f < 0.0 {
                f = f + 1.0;
                qi = qi - 1;
            }
            if f < 1e-6 {
                f = 0.0;
            } else if f > 1.0 - 1e-6 {
                f = 0.0;
                qi = qi + 1;
            }
            let hk = on_col(xm, pc, qi, f, nq);
            if valid(hk) {
                best = max(best, ray_slope(k, alpha, beta, h0, hk));
            }
        }
        k = k + 1.0;
    }
    let t = j.t;
    if t != 0.0 {
        let at = abs(t);
        var rho = -1;
        if t * f32(s) > 0.0 {
            rho = 1;
        }
        var rr = max(ceil(kf * at), 1.0);
        loop {
            let kr = rr / at;
            if kr > kt {
                break;
            }
            let qr = q + rho * i32(rr);
            if qr < 0 || qr >= nq {
                break;
            }
            let pp = f32(p) + f32(s) * kr;
            let c0 = floor(pp);
            let fw = pp - c0;
            let ci = i32(c0);
            if ci < 0 || ci + 1 >= np {
                break;
            }
            let hk = on_grid_line(g(xm, ci, qr), g(xm, ci + 1, qr), fw);
            if valid(hk) {
                best = max(best, ray_slope(kr, alpha, beta, h0, hk));
            }
            rr = rr + 1.0;
        }
    }
    return best;
}

// Column p's pixels beside the line, for direction `dir`, given the hull of everything at
// least NEAR_COLS columns behind (`from_v`): each one's slope into its slot of `far`.
fn observe(l: Line, j: Job, dir: u32, mi: f32, st: i32, p: i32, from_v: u32) {
    let c = col(l.jn, p);
    let q0 = l.m + i32(c.x);
    let f = c.y;
    var hl = line_height(l, p);
    if !valid(hl) {
        hl = g(l.xm, p, clamp(q0, 0, l.nq - 1));
    }
    let th = dir_at(l, j, p);
    var vw = NONE;
    if valid(hl) {
        vw = walk(l, dir, mi, observer(mi, th, hl), from_v);
    }
    let plane = P.rw * P.rh;
    let nr = j.rq1 - j.rq0;
    let t = j.t;
    let dq = -t * f32(st);
    let sd = select(-j.look, j.look, dir == 0u);
    let bs = select(-1.0, 1.0, dir == 0u);
    let y = f32(q0) + f;
    for (var side = 0; side < 2; side = side + 1) {
        let q = q0 + side;
        let wgt = select(f, 1.0 - f, side == 0);
        if wgt <= 0.0 || q < j.rq0 || q >= j.rq1 {
            continue;
        }
        let h0 = g(l.xm, p, q);
        if !valid(h0) {
            continue;
        }
        let o = observer(mi, th, h0);
        var v: u32;
        if vw != NONE && h0 >= hl {
            v = walk(l, dir, mi, o, vw);
        } else {
            v = walk(l, dir, mi, o, from_v);
        }
        // Nothing the pixel's own ray cannot reach.
        var reach = BIG;
        if dq > 1e-12 {
            reach = (f32(l.nq - 1 - q) + 1e-6) / dq;
        } else if dq < -1e-12 {
            reach = (f32(q) + 1e-6) / -dq;
        }
        let dist = abs(f32(i32(v) - p));
        var s: f32;
        if dist <= reach {
            s = slope(l, mi, o, th, v);
        } else {
            let kt = min(reach, dist);
            if kt < f32(NEAR_COLS) {
                continue;
            }
            let ab = pixel_ab(j, l.xm, p, q);
            s = scan(l.jn, j, l.xm, l.np, l.nq, p, q, sd, f32(NEAR_COLS), kt, ab.x, ab.y * bs);
        }
        // The line on the exit side leaves before the ray: near the pixel, the ray itself.
        var line_reach = BIG;
        if dq > 1e-12 {
            line_reach = (f32(l.nq - 1) - y + 1e-6) / dq;
        } else if dq < -1e-12 {
            line_reach = (y + 1e-6) / -dq;
        }
        if line_reach < reach && reach <= EDGE_SCAN {
            let kf = max(f32(NEAR_COLS), floor(line_reach));
            let ab = pixel_ab(j, l.xm, p, q);
            s = max(s, scan(l.jn, j, l.xm, l.np, l.nq, p, q, sd, kf, reach, ab.x, ab.y * bs));
        }
        if s <= NEG {
            continue;
        }
        let idx = u32((p - j.rp0) * nr + (q - j.rq0));
        far[((l.jn * 2u + dir) * plane + idx) * 2u + u32(side)] = ~bitcast<u32>(s);
    }
}

// The sweep's direction `dir`: x mirror, step along p, first and last column in its order.
struct Sweep {
    mi: f32,
    st: i32,
    first: i32,
    last: i32,
}

fn sweep_of(l: Line, j: Job, dir: u32) -> Sweep {
    var w: Sweep;
    var start = l.pa;
    var stop = l.pb;
    if j.step < 0 {
        start = l.pb;
        stop = l.pa;
    }
    w.mi = 1.0;
    w.st = j.step;
    w.first = start;
    w.last = stop;
    if dir == 1u {
        w.mi = -1.0;
        w.st = -j.step;
        w.first = stop;
        w.last = start;
    }
    return w;
}

// Pass 1, one invocation per line: its samples, then per direction the upper hull as a
// persistent chain (each sample's predecessor when it was pushed) and the hull's top after
// each column, so that pass 2 can ask the hull of any column without rebuilding it. (Each
// sample is pushed once and popped at most once: at most 2·(columns) steps a direction.)
@compute @workgroup_size(64)
fn hulls(@builtin(global_invocation_id) gid: vec3<u32>) {
    let su = line_setup(gid.y, gid.x);
    if !su.ok {
        return;
    }
    let l = su.l;
    let j = jobs[l.jn];
    for (var p = l.pa; p <= l.pb; p = p + 1) {
        let h = line_height(l, p);
        var smp: Sample;
        smp.pred0 = NONE;
        smp.pred1 = NONE;
        smp.top0 = NONE;
        smp.top1 = NONE;
        if valid(h) {
            let xy = place(dir_at(l, j, p), h);
            smp.x = xy.x;
            smp.y = xy.y;
        } else {
            smp.x = 0.0;
            smp.y = nodata();
        }
        scratch[l.base + u32(p)] = smp;
    }
    for (var dir = 0u; dir < j.dirs; dir = dir + 1u) {
        let w = sweep_of(l, j, dir);
        var top = NONE;
        var p = w.first;
        loop {
            let i = l.base + u32(p);
            if valid(scratch[i].y) {
                loop {
                    if top == NONE {
                        break;
                    }
                    let u = pred_of(l.base + top, dir);
                    if u == NONE || cross3(w.mi, l.base + u, l.base + top, i) < 0.0 {
                        break;
                    }
                    top = u;
                }
                if dir == 0u {
                    scratch[i].pred0 = top;
                } else {
                    scratch[i].pred1 = top;
                }
                top = u32(p);
            }
            if dir == 0u {
                scratch[i].top0 = top;
            } else {
                scratch[i].top1 = top;
            }
            if p == w.last {
                break;
            }
            p = p + w.st;
        }
    }
}

// Pass 2, one invocation per line, direction and run of `seg` observer columns: each column's
// pixels beside the line ask the hull of everything at least NEAR_COLS columns behind. (Runs
// keep each invocation's loops short: Mesa's lavapipe ends an invocation after 65535 loop
// steps, and a pixel high above a sea walks the whole chain.)
@compute @workgroup_size(64)
fn observers(@builtin(global_invocation_id) gid: vec3<u32>) {
    let su = line_setup(gid.z, gid.x);
    if !su.ok {
        return;
    }
    let l = su.l;
    let j = jobs[l.jn];
    let dir = gid.y % 2u;
    if dir >= j.dirs {
        return;
    }
    let seg = i32(gid.y / 2u);
    let w = sweep_of(l, j, dir);
    let p0 = max(j.rp0 + seg * i32(P.seg), l.pa);
    let p1 = min(min(j.rp0 + (seg + 1) * i32(P.seg), j.rp1), l.pb + 1);
    for (var p = p0; p < p1; p = p + 1) {
        // The CPU sweep's column counter: at least NEAR_COLS columns after the sweep's first.
        let fs = p - w.st * NEAR_COLS;
        if fs < l.pa || fs > l.pb {
            continue;
        }
        let s = scratch[l.base + u32(fs)];
        let from_v = select(s.top1, s.top0, dir == 0u);
        if from_v != NONE {
            observe(l, j, dir, w.mi, w.st, p, from_v);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Pixels.

@compute @workgroup_size(256)
fn pixels(@builtin(global_invocation_id) gid: vec3<u32>) {
    let lin = gid.x + gid.y * P.row_threads;
    let plane = P.rw * P.rh;
    let per_job = 2u * plane;
    if lin >= P.jobs * per_job {
        return;
    }
    let jn = lin / per_job;
    let rem = lin % per_job;
    let dir = rem / plane;
    let idx = rem % plane;
    let j = jobs[jn];
    if dir >= j.dirs {
        return;
    }
    let xm = j.xmajor != 0u;
    let np = select(i32(P.height), i32(P.width), xm);
    let nq = select(i32(P.width), i32(P.height), xm);
    let nr = u32(j.rq1 - j.rq0);
    let p = j.rp0 + i32(idx / nr);
    let q = j.rq0 + i32(idx % nr);
    var x = q;
    var y = p;
    if xm {
        x = p;
        y = q;
    }
    let o = (u32(y) - P.ry0) * P.rw + (u32(x) - P.rx0);
    // Job n's directions are the batch's planes 2n and 2n + 1.
    let op = (jn * 2u + dir) * plane + o;
    let h0 = g(xm, p, q);
    if !valid(h0) {
        outp[op] = nodata();
        return;
    }
    let ab = pixel_ab(j, xm, p, q);
    let sign = select(-1.0, 1.0, dir == 0u);
    let r = P.radius;
    // The near field on the pixel's own ray: (up, hor), compared by cross-multiplying.
    var bu = -1.0;
    var bh = 0.0;
    let ns = select(j.nsteps1, j.nsteps0, dir == 0u);
    let sbase = (jn * 2u + dir) * MAX_STEPS;
    for (var i = 0u; i < ns; i = i + 1u) {
        let sp = steps[sbase + i];
        let nt = select(2, 4, sp.four != 0u);
        var ok = true;
        for (var k = 0; k < 4; k = k + 1) {
            if k < nt && sp.w[k] != 0.0 {
                let pc = p + sp.dc[k];
                let qc = q + sp.dr[k];
                if pc < 0 || pc >= np || qc < 0 || qc >= nq {
                    ok = false;
                }
            }
        }
        if !ok {
            continue;
        }
        var hk = 0.0;
        if sp.four != 0u {
            var good = true;
            for (var k = 0; k < 4; k = k + 1) {
                if sp.w[k] != 0.0 {
                    let v = g(xm, p + sp.dc[k], q + sp.dr[k]);
                    if valid(v) {
                        hk = hk + sp.w[k] * v;
                    } else {
                        good = false;
                    }
                }
            }
            if !good {
                continue;
            }
        } else {
            // A tap of no weight reads the other one (as the CPU's runs do), never its own
            // place, which may lie off the ray (a weight that rounded to 0 in f32).
            var ia = 0;
            if sp.w[0] == 0.0 {
                ia = 1;
            }
            var ib = 1;
            if sp.w[1] == 0.0 {
                ib = ia;
            }
            let a = g(xm, p + sp.dc[ia], q + sp.dr[ia]);
            let b = g(xm, p + sp.dc[ib], q + sp.dr[ib]);
            hk = on_grid_line(a, b, sp.w[1]);
            if !valid(hk) {
                continue;
            }
        }
        let k = sp.k;
        let xx = k * sign * ab.y;
        let tt = k * ab.x / (1.0 + xx);
        let qq = tt * tt;
        let drop = (r + h0) * qq / (1.0 + sqrt(1.0 + qq));
        let up = (hk - h0) - drop;
        let hor = (r + hk) * tt;
        if up * bh > bu * hor {
            bu = up;
            bh = hor;
        }
    }
    var s = NEG;
    if bh > 0.0 {
        s = bu / bh;
    }
    // The far field: the two lines beside the pixel, weighted by nearness.
    let f = col(jn, p).y;
    let fb = ((jn * 2u + dir) * plane + idx) * 2u;
    var num = 0.0;
    var den = 0.0;
    let e0 = far[fb];
    if e0 != 0u && 1.0 - f > 0.0 {
        num = num + (1.0 - f) * bitcast<f32>(~e0);
        den = den + (1.0 - f);
    }
    let e1 = far[fb + 1u];
    if e1 != 0u && f > 0.0 {
        num = num + f * bitcast<f32>(~e1);
        den = den + f;
    }
    if den > 0.0 {
        s = max(s, num / den);
    }
    // The zero-distance slope.
    var zp = j.zp0;
    var zwp = j.zwp0;
    var zq = j.zq0;
    var zwq = j.zwq0;
    if dir == 1u {
        zp = j.zp1;
        zwp = j.zwp1;
        zq = j.zq1;
        zwq = j.zwq1;
    }
    var dh = 0.0;
    var okz = true;
    if zp != 0 {
        let pn = p + zp;
        if pn < 0 || pn >= np || q < j.rq0 || q >= j.rq1 {
            okz = false;
        } else {
            let v = g(xm, pn, q);
            if valid(v) {
                dh = dh + (v - h0) * zwp;
            } else {
                okz = false;
            }
        }
    }
    if zq != 0 {
        let qn = q + zq;
        if qn < 0 || qn >= nq {
            okz = false;
        } else {
            let v = g(xm, p, qn);
            if valid(v) {
                dh = dh + (v - h0) * zwq;
            } else {
                okz = false;
            }
        }
    }
    if okz {
        let s0 = dh / ((r + h0) * ab.x * j.adp);
        if s0 > s {
            s = s0;
        }
    }
    if s <= NEG {
        outp[op] = -90.0;
    } else {
        outp[op] = atan_deg(s);
    }
}

// The arc tangent in degrees by Cephes' atanf (range reduction and a degree-4 polynomial, within
// 2 ulp), not the GPU's own, whose accuracy Vulkan leaves at 4096 ulp.
fn atan_deg(s: f32) -> f32 {
    var x = abs(s);
    var y0 = 0.0;
    if x > 2.414213562373095 {
        y0 = 1.5707963267948966;
        x = -1.0 / x;
    } else if x > 0.41421356237309503 {
        y0 = 0.7853981633974483;
        x = (x - 1.0) / (x + 1.0);
    }
    let z = x * x;
    let y = y0 + ((((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z
        - 3.33329491539e-1) * z * x + x);
    return select(y, -y, s < 0.0) * DEG;
}
