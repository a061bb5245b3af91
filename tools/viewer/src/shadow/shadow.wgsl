// The GPU twins of penumbra's CPU shadow methods (src/shadow/trace.rs, and the Fourier lookup
// of src/shadow/mod.rs), over one tile's context raster on its face's extended gnomonic plane.
//
// `shadow_lit(p)`: lit fraction of the sun's disc at raster texel p (hard methods: 0 or 1);
// negative over no data. f32 throughout, so the geometry is written without cancellation:
// heights relative to the observer's, 1 − cos ψ as b²/(n(n + a)), acos near 1 through asin.

struct ShadowParams {
    // Face normal and gnomonic plane axes (xyz).
    face_n: vec4<f32>,
    face_u: vec4<f32>,
    face_v: vec4<f32>,
    // Unit sun direction, body frame (xyz); w: its angular radius (degrees, in [0, 60]).
    sun: vec4<f32>,
    // Raster origin in global face pixels (x, y), raster width and height.
    raster: vec4<i32>,
    // Face pixels S, body radius (m), lowest terrain (m) for the floor, highest terrain of the
    // raster (m).
    geo: vec4<f32>,
    // Method (0 dp, 1 uniform, 2 extrema, 3 fourier, 4 extrema-soft, 5 dp-jung), uniform steps, fixed DP
    // runs (0: auto) or the Fourier disc model (0 constant, 1 segment, 2 slices, 3 exact),
    // pyramid levels, Fourier coefficients.
    method: vec4<i32>,
    // The tile's interior in the raster: x0, y0, w, h.
    rect: vec4<i32>,
    // N′ of the fixed DP runs, four per vec4.
    runs: array<vec4<i32>, 4>,
    // Level m of the min/max pyramid in the atlas: x, y offset, width, height.
    levels: array<vec4<i32>, 16>,
}

@group(1) @binding(0) var<uniform> shadow_params: ShadowParams;
// Context heights (m); no data as -1e30.
@group(1) @binding(1) var shadow_heights: texture_2d<f32>;
// Min/max pyramid levels side by side: (max, min), -1e30 standing for −∞.
@group(1) @binding(2) var shadow_extrema: texture_2d<f32>;
// Fourier coefficients of tile texel (i, j), expanded from the pyramid when the tile is loaded:
// texel (i·P + q, j) holds slots 2q and 2q + 1 (re, im, re, im), P = ⌈K/2⌉.
@group(1) @binding(3) var shadow_fourier: texture_2d<f32>;

const SH_NEG: f32 = -1.0e30;
const SH_BIG: f32 = 1.0e30;
const SH_NODATA: f32 = -1.0e29;
const SH_NEAR_PX: f32 = 1.5;
const SH_PI: f32 = 3.14159265358979;
const SH_TAU: f32 = 6.28318530717959;
const SH_DEG: f32 = 57.2957795130823;
const SH_MAX_K: i32 = 32;
const SH_STRIPS: i32 = 256;

struct ShRay {
    x0: f32,
    y0: f32,
    cx: f32,
    cy: f32,
    h0: f32,
    r0: f32,
    a0: f32,
    a1: f32,
    b1: f32,
    kappa: f32,
    // The origin for walks over the min/max pyramid: (x0, y0), except that a ray along the
    // raster's last column (or row) starts in the last cells, as the CPU's walk does.
    wx: f32,
    wy: f32,
}

struct ShAxis {
    i: i32,
    step: i32,
    next: f32,
    delta: f32,
}

fn sh_height(x: i32, y: i32) -> f32 {
    let p = shadow_params.raster;
    if x < 0 || y < 0 || x >= p.z || y >= p.w {
        return SH_NEG;
    }
    return textureLoad(shadow_heights, vec2<i32>(x, y), 0).x;
}

fn sh_valid(h: f32) -> bool {
    return h > SH_NODATA;
}

// Unit up vector of raster texel (x, y) and the length of its plane point.
fn sh_plane_point(x: i32, y: i32) -> vec3<f32> {
    let p = shadow_params;
    let s = p.geo.x;
    let u = -1.0 + 2.0 * (f32(p.raster.x + x) + 0.5) / s;
    let v = 1.0 - 2.0 * (f32(p.raster.y + y) + 0.5) / s;
    return p.face_n.xyz + u * p.face_u.xyz + v * p.face_v.xyz;
}

// Plane azimuth (radians, [0, 2π)) of direction d's tangent part at `up`.
fn sh_plane_azimuth(up: vec3<f32>, d: vec3<f32>) -> f32 {
    let p = shadow_params;
    let np = dot(p.face_n.xyz, up);
    let nt = dot(p.face_n.xyz, d);
    let x = dot(p.face_u.xyz, d) * np - dot(p.face_u.xyz, up) * nt;
    let y = dot(p.face_v.xyz, d) * np - dot(p.face_v.xyz, up) * nt;
    var a = atan2(y, x);
    if a < 0.0 {
        a += SH_TAU;
    }
    return a;
}

// Elevation (degrees) of unit direction d above the horizontal at `up`.
fn sh_elevation_deg(up: vec3<f32>, d: vec3<f32>) -> f32 {
    let z = dot(d, up);
    return atan2(z, length(d - z * up)) * SH_DEG;
}

fn sh_tan_deg(d: f32) -> f32 {
    if d >= 90.0 {
        return SH_BIG;
    }
    if d <= -90.0 {
        return SH_NEG;
    }
    return tan(d / SH_DEG);
}

// acos(q) for q ≤ 1 given 1 − q (accurate near q = 1).
fn sh_acos_1m(one_minus_q: f32) -> f32 {
    return 2.0 * asin(sqrt(clamp(0.5 * one_minus_q, 0.0, 1.0)));
}

// The floor (degrees): the tangent to the sphere of the lowest terrain.
fn sh_floor_deg(h0: f32) -> f32 {
    let p = shadow_params;
    let tmin = p.geo.z;
    let hh = max(h0, tmin);
    return -sh_acos_1m((hh - tmin) / (p.geo.y + hh)) * SH_DEG;
}

fn sh_segment_fraction(d: f32) -> f32 {
    if d <= -1.0 {
        return 1.0;
    }
    if d >= 1.0 {
        return 0.0;
    }
    return clamp((acos(d) - d * sqrt(max(1.0 - d * d, 0.0))) / SH_PI, 0.0, 1.0);
}

// ---------------------------------------------------------------------------------------------
// The ray: the plane line (x0, y0) + s·(cx, cy), s in plane pixels, a great circle.

fn sh_ray(x: i32, y: i32, h0: f32, phi: f32) -> ShRay {
    let p = shadow_params;
    let pp = sh_plane_point(x, y);
    let n0 = length(pp);
    let ph = pp / n0;
    let c = cos(phi);
    let s = sin(phi);
    let k = 2.0 / p.geo.x;
    let w = k * (c * p.face_u.xyz + s * p.face_v.xyz);
    var r: ShRay;
    r.x0 = f32(x);
    r.y0 = f32(y);
    r.cx = c;
    r.cy = -s;
    // The CPU makes components below 1e-12 exactly 0 (a ray along a row or column); in f32
    // cos and sin of a multiple of π/2 are only within 1e-7 of 0.
    if abs(r.cx) <= 2e-7 {
        r.cx = 0.0;
    }
    if abs(r.cy) <= 2e-7 {
        r.cy = 0.0;
    }
    r.h0 = h0;
    r.r0 = p.geo.y + h0;
    r.a0 = n0;
    r.a1 = dot(w, ph);
    r.b1 = length(cross(w, ph));
    let gm = r.r0 * r.b1 / n0;
    r.kappa = gm * gm / (2.0 * r.r0);
    r.wx = r.x0;
    if r.cx == 0.0 {
        r.wx = min(r.x0, f32(p.raster.z) - 1.5);
    }
    r.wy = r.y0;
    if r.cy == 0.0 {
        r.wy = min(r.y0, f32(p.raster.w) - 1.5);
    }
    return r;
}

// Slope (tan of elevation) of terrain dh above the observer's height at distance s > 0:
// (r·a − r0·n)/(r·b) = (dh·a − r0·b²/(n + a))/(r·b).
fn sh_slope_rel(ray: ShRay, s: f32, dh: f32) -> f32 {
    let a = ray.a0 + s * ray.a1;
    let b = s * ray.b1;
    let n = sqrt(a * a + b * b);
    let r = ray.r0 + dh;
    return (dh * a - ray.r0 * b * b / (n + a)) / (r * b);
}

fn sh_snap(x: f32, hi: f32) -> f32 {
    if x < 0.0 && x > -1e-4 {
        return 0.0;
    }
    if x > hi && x < hi + 1e-4 {
        return hi;
    }
    return x;
}

// Bilinear height relative to the observer at fractional texel (x, y) (no-data taps left out);
// SH_NEG when none is left or outside.
fn sh_bilinear_rel(xi_: f32, yi_: f32, h0: f32) -> f32 {
    let wm = f32(shadow_params.raster.z - 1);
    let hm = f32(shadow_params.raster.w - 1);
    let x = sh_snap(xi_, wm);
    let y = sh_snap(yi_, hm);
    if !(x >= 0.0 && y >= 0.0 && x <= wm && y <= hm) {
        return SH_NEG;
    }
    let fx0 = floor(x);
    let fy0 = floor(y);
    let xi = i32(fx0);
    let yi = i32(fy0);
    let fx = x - fx0;
    let fy = y - fy0;
    let w00 = (1.0 - fx) * (1.0 - fy);
    let w10 = fx * (1.0 - fy);
    let w01 = (1.0 - fx) * fy;
    let w11 = fx * fy;
    let h00 = sh_height(xi, yi);
    let h10 = sh_height(xi + 1, yi);
    let h01 = sh_height(xi, yi + 1);
    let h11 = sh_height(xi + 1, yi + 1);
    if sh_valid(h00) && sh_valid(h10) && sh_valid(h01) && sh_valid(h11) {
        // All four taps hold terrain (the common case): the sums below, straight.
        let acc = w00 * (h00 - h0) + w10 * (h10 - h0) + w01 * (h01 - h0) + w11 * (h11 - h0);
        return acc / (w00 + w10 + w01 + w11);
    }
    // A tap without terrain, or outside the raster with no weight: left out.
    var acc = 0.0;
    var wsum = 0.0;
    let ws = array<f32, 4>(w00, w10, w01, w11);
    let hs = array<f32, 4>(h00, h10, h01, h11);
    for (var k = 0; k < 4; k++) {
        let w = ws[k];
        if w == 0.0 || !sh_valid(hs[k]) {
            continue;
        }
        acc += w * (hs[k] - h0);
        wsum += w;
    }
    if wsum > 0.0 {
        return acc / wsum;
    }
    return SH_NEG;
}

fn sh_slope_at(ray: ShRay, s: f32) -> f32 {
    let v = sh_bilinear_rel(ray.x0 + s * ray.cx, ray.y0 + s * ray.cy, ray.h0);
    if v == SH_NEG {
        return SH_NEG;
    }
    return sh_slope_rel(ray, s, v);
}

fn sh_axis(x: f32, d: f32, s0: f32) -> ShAxis {
    let fl = floor(x);
    var a: ShAxis;
    if d > 1e-12 {
        a.i = i32(fl);
        a.step = 1;
        a.next = (fl + 1.0 - x) / d + s0;
        a.delta = 1.0 / d;
    } else if d < -1e-12 {
        var c = fl;
        if fl == x {
            c = fl - 1.0;
        }
        a.i = i32(c);
        a.step = -1;
        a.next = (x - c) / -d + s0;
        a.delta = -1.0 / d;
    } else {
        a.i = i32(fl);
        a.step = 0;
        a.next = SH_BIG;
        a.delta = SH_BIG;
    }
    return a;
}

fn sh_advance(a: ptr<function, ShAxis>, s: f32) {
    if (*a).next <= s {
        (*a).i += (*a).step;
        (*a).next += (*a).delta;
    }
}

// Cell (ix, iy)'s bilinear surface along the ray, relative to the observer: height c0 + s·c1 +
// s²·c2 at distance s, from its corners h = (h00, h10, h01, h11).
fn sh_cell_line(ray: ShRay, ix: i32, iy: i32, h: vec4<f32>) -> vec3<f32> {
    let r00 = h.x - ray.h0;
    let a = h.y - h.x;
    let b = h.z - h.x;
    let c = (h.w - h.y) - (h.z - h.x);
    let ex = ray.x0 - f32(ix);
    let ey = ray.y0 - f32(iy);
    let c0 = r00 + a * ex + b * ey + c * ex * ey;
    let c1 = a * ray.cx + b * ray.cy + c * (ex * ray.cy + ey * ray.cx);
    return vec3<f32>(c0, c1, c * ray.cx * ray.cy);
}

// The slope at the stationary point of that line's slope strictly inside (s0, s1) (SH_NEG when
// there is none): with the curvature drop κ·s², the slope (c0 + c1·s + (c2 − κ)·s²)/s is
// stationary at s = √(c0 / (c2 − κ)).
fn sh_cell_peak(ray: ShRay, c: vec3<f32>, s0: f32, s1: f32) -> f32 {
    let cc = c.z - ray.kappa;
    if c.x != 0.0 && cc != 0.0 && c.x / cc > 0.0 {
        let st = sqrt(c.x / cc);
        if st > s0 && st < s1 {
            return sh_slope_rel(ray, st, c.x + st * (c.y + st * c.z));
        }
    }
    return SH_NEG;
}

// The largest slope over the continuous bilinear surface along the ray for s in
// [s_from, s_to], cell by cell (the CPU's Ray::max_over).
fn sh_max_over(ray: ShRay, s_from: f32, s_to: f32, floor_: f32) -> f32 {
    var best = floor_;
    let nx = shadow_params.raster.z;
    let ny = shadow_params.raster.w;
    let w1 = f32(nx - 1);
    let h1 = f32(ny - 1);
    let x = ray.x0 + s_from * ray.cx;
    let y = ray.y0 + s_from * ray.cy;
    if !(x >= 0.0 && y >= 0.0 && x <= w1 && y <= h1) || s_from >= s_to {
        return best;
    }
    var ax = sh_axis(x, ray.cx, s_from);
    var ay = sh_axis(y, ray.cy, s_from);
    if s_from > 0.0 {
        best = max(best, sh_slope_at(ray, s_from));
    }
    var s = s_from;
    for (var guard = 0; guard < 1000000; guard++) {
        if !(s < s_to && ax.i >= 0 && ay.i >= 0 && ax.i < nx && ay.i < ny) {
            break;
        }
        let ix = ax.i;
        let iy = ay.i;
        let s_next = min(min(ax.next, ay.next), s_to);
        let h00 = sh_height(ix, iy);
        let h10 = sh_height(ix + 1, iy);
        let h01 = sh_height(ix, iy + 1);
        let h11 = sh_height(ix + 1, iy + 1);
        if sh_valid(h00) && sh_valid(h10) && sh_valid(h01) && sh_valid(h11) {
            let c = sh_cell_line(ray, ix, iy, vec4<f32>(h00, h10, h01, h11));
            best = max(best, sh_slope_rel(ray, s_next, c.x + s_next * (c.y + s_next * c.z)));
            best = max(best, sh_cell_peak(ray, c, s, s_next));
        } else {
            best = max(best, sh_slope_at(ray, s_next));
        }
        s = s_next;
        sh_advance(&ax, s);
        sh_advance(&ay, s);
    }
    return best;
}

// The largest slope over s in [sa, sb], a stretch of the ray inside one cell (a level-0 texel
// of the min/max pyramid): sh_max_over's work for that cell without its walk. The cell is the
// one under the stretch's middle; one without terrain at a corner goes to sh_max_over.
fn sh_cell_max(ray: ShRay, sa: f32, sb: f32) -> f32 {
    let mid = 0.5 * (sa + sb);
    let ix = clamp(i32(floor(ray.x0 + mid * ray.cx)), 0, shadow_params.raster.z - 2);
    let iy = clamp(i32(floor(ray.y0 + mid * ray.cy)), 0, shadow_params.raster.w - 2);
    let h00 = sh_height(ix, iy);
    let h10 = sh_height(ix + 1, iy);
    let h01 = sh_height(ix, iy + 1);
    let h11 = sh_height(ix + 1, iy + 1);
    if !(sh_valid(h00) && sh_valid(h10) && sh_valid(h01) && sh_valid(h11)) {
        return sh_max_over(ray, sa, sb, SH_NEG);
    }
    let c = sh_cell_line(ray, ix, iy, vec4<f32>(h00, h10, h01, h11));
    var best = sh_slope_rel(ray, sb, c.x + sb * (c.y + sb * c.z));
    if sa > 0.0 {
        best = max(best, sh_slope_rel(ray, sa, c.x + sa * (c.y + sa * c.z)));
    }
    return max(best, sh_cell_peak(ray, c, sa, sb));
}

// Distance (plane pixels) at which the ray leaves the raster.
fn sh_raster_exit(ray: ShRay) -> f32 {
    let w1 = f32(shadow_params.raster.z - 1);
    let h1 = f32(shadow_params.raster.w - 1);
    var ex = SH_BIG;
    if ray.cx > 1e-12 {
        ex = (w1 - ray.x0) / ray.cx;
    } else if ray.cx < -1e-12 {
        ex = ray.x0 / -ray.cx;
    }
    var ey = SH_BIG;
    if ray.cy > 1e-12 {
        ey = (h1 - ray.y0) / ray.cy;
    } else if ray.cy < -1e-12 {
        ey = ray.y0 / -ray.cy;
    }
    return max(min(ex, ey), 0.0);
}

// Distance beyond which no terrain of the raster can reach slope t.
fn sh_exit(ray: ShRay, t: f32) -> f32 {
    let edge = sh_raster_exit(ray);
    let hmax = shadow_params.geo.w;
    if hmax <= SH_NODATA {
        return edge;
    }
    let e = atan(t);
    let rmax = shadow_params.geo.y + hmax;
    // 1 − r0·cos e / rmax, without cancellation.
    let se = sin(0.5 * e);
    let one_minus_c = ((hmax - ray.h0) + ray.r0 * 2.0 * se * se) / rmax;
    if one_minus_c <= 0.0 {
        return edge;
    }
    let psi = sh_acos_1m(one_minus_c) - e;
    if psi <= 0.0 {
        return 0.0;
    }
    if psi >= 0.5 * SH_PI {
        return edge;
    }
    let tp = tan(psi);
    let den = ray.b1 - ray.a1 * tp;
    if den <= 0.0 {
        return edge;
    }
    return min(ray.a0 * tp / den, edge);
}

// The largest slope terrain no higher than h can have over s in [sa, sb].
fn sh_max_slope(ray: ShRay, sa: f32, sb: f32, h: f32) -> f32 {
    if h <= SH_NODATA {
        return SH_NEG;
    }
    let dh = h - ray.h0;
    if dh >= 0.0 {
        return sh_slope_rel(ray, sa, dh);
    }
    let q = 1.0 + dh / ray.r0;
    let tp = sqrt(max((-dh / ray.r0) * (1.0 + q), 0.0)) / q;
    let den = ray.b1 - ray.a1 * tp;
    var s_star = SH_BIG;
    if den > 0.0 {
        s_star = ray.a0 * tp / den;
    }
    return sh_slope_rel(ray, clamp(s_star, sa, sb), dh);
}

// The exact horizon slope near the observer: its directional derivative and the cells out to
// NEAR_PX.
fn sh_near(ray: ShRay, x: i32, y: i32, phi: f32) -> f32 {
    let cx = cos(phi);
    let cy = -sin(phi);
    let h0 = ray.h0;
    var dh = 0.0;
    var ok = true;
    if abs(cx) > 1e-12 {
        let hx = sh_height(x + i32(sign(cx)), y);
        ok = ok && sh_valid(hx);
        dh += (hx - h0) * abs(cx);
    }
    if abs(cy) > 1e-12 {
        let hy = sh_height(x, y + i32(sign(cy)));
        ok = ok && sh_valid(hy);
        dh += (hy - h0) * abs(cy);
    }
    var best = SH_NEG;
    if ok {
        best = dh / (ray.r0 * ray.b1 / ray.a0);
    }
    return sh_max_over(ray, 0.0, SH_NEAR_PX, best);
}

// ---------------------------------------------------------------------------------------------
// The exact search over the min/max pyramid, without a stack: a texel is named by its level and
// index, its children and parent by integer arithmetic, so that a lane's whole state is a few
// scalars (on lavapipe a stack of walkers in private memory doubled the cost of every step).

// Inverse of a direction component (0 for a component that is 0).
fn sh_inv(c: f32) -> f32 {
    if c == 0.0 {
        return 0.0;
    }
    return 1.0 / c;
}

// Distance at which the ray leaves [i·q, (i+1)·q) along one axis (SH_BIG: never).
fn sh_leave(x0: f32, c: f32, ic: f32, i: i32, q: f32) -> f32 {
    if c > 0.0 {
        return (f32(i + 1) * q - x0) * ic;
    }
    if c < 0.0 {
        return (f32(i) * q - x0) * ic;
    }
    return SH_BIG;
}

// Index (along one axis) of the child of texel i (children of size h) that the ray is in at
// coordinate x, moving by c: on their boundary, the one it moves into (c = 0: the upper one, as
// floor).
fn sh_child(i: i32, x: f32, c: f32, h: f32) -> i32 {
    let mid = f32(2 * i + 1) * h;
    if x > mid || (x == mid && c >= 0.0) {
        return 2 * i + 1;
    }
    return 2 * i;
}

// The ray's stretch (s_in, s_out) inside [lo_edge, lo_edge + q) along one axis; for a ray
// without motion along it, everything or nothing.
fn sh_slab(x0: f32, c: f32, ic: f32, lo_edge: f32, q: f32) -> vec2<f32> {
    if c == 0.0 {
        if x0 >= lo_edge && x0 < lo_edge + q {
            return vec2<f32>(-SH_BIG, SH_BIG);
        }
        return vec2<f32>(SH_BIG, -SH_BIG);
    }
    let t1 = (lo_edge - x0) * ic;
    let t2 = (lo_edge + q - x0) * ic;
    return vec2<f32>(min(t1, t2), max(t1, t2));
}

// The exact horizon slope over s in [sa, sb], searched from the level whose texels are about as
// long as the stretch (two or three of them under it) down: a texel whose
// bound cannot rise above max(best, lo) is passed whole; one that can is entered, down to its
// cells, searched exactly (sh_cell_max). Stops once the slope reaches hi (the disc's top); a
// texel whose lowest terrain reaches hi ends it with that terrain's slope. Returns the largest
// of `best` and what it found.
fn sh_search(ray: ShRay, sa: f32, sb: f32, best_in: f32, lo: f32, hi: f32) -> f32 {
    var best = best_in;
    if best >= hi || !(sa < sb) {
        return best;
    }
    let icx = sh_inv(ray.cx);
    let icy = sh_inv(ray.cy);
    let stx = i32(sign(ray.cx));
    let sty = i32(sign(ray.cy));
    let top = shadow_params.method.z - 1;
    let major = max(abs(ray.cx), abs(ray.cy));
    var m = min(i32(firstLeadingBit(u32(max((sb - sa) * major, 1.0)))), top);
    var q = f32(1 << u32(m));
    var s = sa;
    let x = ray.wx + sa * ray.cx;
    let y = ray.wy + sa * ray.cy;
    if !(x >= 0.0 && y >= 0.0) {
        return best;
    }
    var ix = sh_axis(x / q, ray.cx / q, sa).i;
    var iy = sh_axis(y / q, ray.cy / q, sa).i;
    for (var guard = 0; guard < 1000000; guard++) {
        if !(s < sb) {
            break;
        }
        let l = shadow_params.levels[m];
        if ix < 0 || iy < 0 || ix >= l.z || iy >= l.w {
            break;
        }
        let ex = sh_leave(ray.x0, ray.cx, icx, ix, q);
        let ey = sh_leave(ray.y0, ray.cy, icy, iy, q);
        let s_out = max(min(min(ex, ey), sb), s);
        let e = textureLoad(shadow_extrema, vec2<i32>(l.x + ix, l.y + iy), 0).xy;
        if sh_max_slope(ray, s, s_out, e.x) > max(best, lo) {
            if e.y > SH_NODATA {
                let low = sh_max_slope(ray, s, s_out, e.y);
                if low >= hi {
                    best = max(best, low);
                    break;
                }
            }
            if m > 0 {
                // Into the child the ray is in at s.
                m -= 1;
                q *= 0.5;
                ix = sh_child(ix, ray.wx + s * ray.cx, ray.cx, q);
                iy = sh_child(iy, ray.wy + s * ray.cy, ray.cy, q);
                continue;
            }
            best = max(best, sh_cell_max(ray, s, s_out));
            if best >= hi {
                break;
            }
        }
        // On to the next texel of this level, and up a level where the step left the parent
        // (one level per step: a loop climbing further cost more on lavapipe than it saved).
        s = s_out;
        let ox = ix;
        let oy = iy;
        if ex <= ey {
            ix += stx;
        }
        if ey <= ex {
            iy += sty;
        }
        if m < top && ((ix >> 1u) != (ox >> 1u) || (iy >> 1u) != (oy >> 1u)) {
            m += 1;
            q *= 2.0;
            ix = ix >> 1u;
            iy = iy >> 1u;
        }
    }
    return best;
}

// ---------------------------------------------------------------------------------------------
// The methods.

fn sh_uniform(ray: ShRay, steps: i32, lo: f32) -> f32 {
    let end = sh_exit(ray, lo);
    var best = SH_NEG;
    if end <= 0.0 || steps <= 0 {
        return best;
    }
    let ds = end / f32(steps);
    for (var k = 1; k <= steps; k++) {
        best = max(best, sh_slope_at(ray, f32(k) * ds));
    }
    return best;
}

// Jung et al.'s DP as published (the CPU's Method::JungDp, `dp-jung`): at each level the one
// texel of largest bound among those under the ray, no return to the others. x: the run's
// horizon slope (SH_NEG when no texel beats floor_); y: the largest bound among the texels it
// passed over (SH_NEG: none), which tells `dp` whether the run's answer is already exact.
fn sh_dp_jung_run(ray: ShRay, a: f32, b: f32, m0: i32, floor_: f32) -> vec2<f32> {
    var passed = SH_NEG;
    let icx = sh_inv(ray.cx);
    let icy = sh_inv(ray.cy);
    // Level m0: the run's stretch is one texel long along the ray's major axis, so the texels
    // under it are the one it starts in and its neighbours ahead in x, in y and in both.
    let q0 = f32(1 << u32(m0));
    let x = ray.wx + a * ray.cx;
    let y = ray.wy + a * ray.cy;
    if !(x >= 0.0 && y >= 0.0) {
        return vec2<f32>(SH_NEG, passed);
    }
    // Each level: the (up to three) texels of a 2×2 block the ray crosses over [ca, cz], in
    // straight-line code instead of a walk (Jung et al.'s own formulation): the same texels and
    // spans as the walk's, the first along the ray among equal bounds. Below m0 the block is
    // the children of the texel chosen.
    var ca = a;
    var cz = b;
    var tx = sh_axis(x / q0, ray.cx / q0, a).i;
    var ty = sh_axis(y / q0, ray.cy / q0, a).i;
    var sx = i32(sign(ray.cx));
    var sy = i32(sign(ray.cy));
    for (var m = m0; m >= 0; m--) {
        let q = f32(1 << u32(m));
        let l = shadow_params.levels[m];
        var nb = floor_;
        var nfound = false;
        var na = 0.0;
        var nz = 0.0;
        var nx = 0;
        var ny = 0;
        for (var k = 0; k < 4; k++) {
            let cx = tx + (k & 1) * sx;
            let cy = ty + (k >> 1u) * sy;
            if ((k & 1) == 1 && sx == 0) || ((k >> 1u) == 1 && sy == 0) {
                continue;
            }
            let spx = sh_slab(ray.wx, ray.cx, icx, f32(cx) * q, q);
            let spy = sh_slab(ray.wy, ray.cy, icy, f32(cy) * q, q);
            let s_in = max(max(spx.x, spy.x), ca);
            let s_out = min(min(spx.y, spy.y), cz);
            if !(s_out > s_in) || cx < 0 || cy < 0 || cx >= l.z || cy >= l.w {
                continue;
            }
            let hmax = textureLoad(shadow_extrema, vec2<i32>(l.x + cx, l.y + cy), 0).x;
            let bound = sh_max_slope(ray, s_in, s_out, hmax);
            if bound > nb || (nfound && bound == nb && s_in < na) {
                if nfound {
                    passed = max(passed, nb);
                }
                nb = bound;
                na = s_in;
                nz = s_out;
                nx = cx;
                ny = cy;
                nfound = true;
            } else {
                passed = max(passed, bound);
            }
        }
        if !nfound {
            return vec2<f32>(SH_NEG, passed);
        }
        ca = na;
        cz = nz;
        tx = 2 * nx;
        ty = 2 * ny;
        sx = 1;
        sy = 1;
    }
    return vec2<f32>(sh_cell_max(ray, ca, cz), passed);
}

fn sh_dp(ray: ShRay, x: i32, y: i32, phi: f32, lo: f32, hi: f32, jung: bool) -> f32 {
    let p = shadow_params;
    var best = sh_near(ray, x, y, phi);
    let end = sh_exit(ray, lo);
    let major = max(abs(ray.cx), abs(ray.cy));
    let top = p.method.z - 1;
    let nruns = p.method.y;
    var a = SH_NEAR_PX;
    // The largest bound among the texels the descents passed over that could beat what their
    // run found, and the stretch [first, to] of those runs.
    var passed = SH_NEG;
    var first = -1.0;
    var to = 0.0;
    for (var k = 0; k <= 4096; k++) {
        if a >= end || best >= hi {
            break;
        }
        var levels = 5;
        if nruns > 0 {
            if k >= nruns {
                break;
            }
            levels = p.runs[k / 4][k % 4];
        } else {
            let covered = max(a * major, 1.0);
            levels = max(i32(firstLeadingBit(u32(covered))) + 1, 5);
        }
        let m0 = min(levels - 1, top);
        let len = f32(1 << u32(m0)) / major;
        let b = a + len;
        let fl = max(best, lo);
        let r = sh_dp_jung_run(ray, a, min(b, end), m0, fl);
        if r.y > max(r.x, fl) {
            // A texel this run passed over could beat what it found.
            passed = max(passed, r.y);
            if first < 0.0 {
                first = a;
            }
            to = min(b, end);
        }
        best = max(best, r.x);
        a = b;
    }
    // `dp`: where a texel some descent passed over could still rise above the best the runs
    // found, one exact search over those runs' stretch,
    // passing every texel that cannot (sh_search; the CPU's dp refines run by run, with a stack
    // of the texels passed over: the same exact answer). Elsewhere the runs' answer is exact.
    if !jung && passed > max(best, lo) && best < hi {
        best = sh_search(ray, first, to, best, lo, hi);
    }
    return best;
}

// Timokhin & Mikhaylyuk's traversal: whether the terrain reaches slope t along the ray.
fn sh_extrema_dark(ray: ShRay, x: i32, y: i32, phi: f32, t: f32) -> bool {
    if sh_near(ray, x, y, phi) >= t {
        return true;
    }
    let end = sh_exit(ray, t);
    if end <= SH_NEAR_PX {
        return false;
    }
    // Texels whose highest terrain stays below t are passed, one whose lowest reaches it ends
    // the walk, cells are searched exactly.
    return sh_search(ray, SH_NEAR_PX, end, SH_NEG, t, t) >= t;
}

// The min/max traversal as a soft method (the CPU's extrema_soft): the exact horizon slope in
// the ray's azimuth, clamped below at lo (anything lower leaves the disc whole) and found only
// up to hi (anything higher hides it). Texels that cannot rise above the best slope found or
// lo are skipped; the walk stops once a texel hides the disc's top.
fn sh_extrema_soft(ray: ShRay, x: i32, y: i32, phi: f32, lo: f32, hi: f32) -> f32 {
    let best = sh_near(ray, x, y, phi);
    if best >= hi {
        return best;
    }
    let end = sh_exit(ray, lo);
    if end <= SH_NEAR_PX {
        return best;
    }
    return sh_search(ray, SH_NEAR_PX, end, best, lo, hi);
}

// Jung et al.'s disc occlusion: a horizon of slope a (floored) hides the segment below it.
fn sh_occlusion(a: f32, floor_deg: f32, el: f32, r: f32) -> f32 {
    var alpha = floor_deg;
    if a > SH_NODATA {
        alpha = max(atan(a) * SH_DEG, floor_deg);
    }
    if r <= 0.0 {
        if el > alpha {
            return 1.0;
        }
        if el < alpha {
            return 0.0;
        }
        return 0.5;
    }
    return sh_segment_fraction((alpha - el) / r);
}

// ---------------------------------------------------------------------------------------------
// Fourier: the tile's horizon pyramid and the disc models of penumbra::fourier::sun: constant
// (method.y 0), segment (1), slices (2), exact (3; 256 strips).

alias ShCoef = array<vec2<f32>, 32>;

// Coefficient slots 2q, 2q + 1 of tile texel (i, j).
fn sh_fourier_pair(i: i32, j: i32, q: i32) -> vec4<f32> {
    let pairs = (shadow_params.method.w + 1) / 2;
    return textureLoad(shadow_fourier, vec2<i32>(i * pairs + q, j), 0);
}

// All 32 slots of tile texel (i, j), zero past K, for the models that evaluate the series at
// many azimuths.
fn sh_fourier_coefficients(coef: ptr<function, ShCoef>, i: i32, j: i32) {
    let k = shadow_params.method.w;
    // Constant trip counts (all 32 slots, zero past k): lavapipe corrupted the array when
    // the loops ran k times.
    for (var q = 0; q < 16; q++) {
        var v = vec4<f32>(0.0);
        if 2 * q < k {
            v = sh_fourier_pair(i, j, q);
        }
        (*coef)[2 * q] = select(vec2<f32>(0.0), v.xy, 2 * q < k);
        (*coef)[2 * q + 1] = select(vec2<f32>(0.0), v.zw, 2 * q + 1 < k);
    }
}

// The series of tile texel (i, j) at two azimuths at once, straight from the texture (no
// array): ⌈K/2⌉ fetches, one sin/cos per azimuth, then rotations (the constant model uses x).
fn sh_series_at(i: i32, j: i32, ta: f32, tb: f32) -> vec2<f32> {
    let k = shadow_params.method.w;
    let ra = vec2<f32>(cos(ta), sin(ta));
    let rb = vec2<f32>(cos(tb), sin(tb));
    // e^{i·kθ} for the pair's first slot, per azimuth.
    var ea = vec2<f32>(1.0, 0.0);
    var eb = vec2<f32>(1.0, 0.0);
    var sum = vec2<f32>(0.0);
    let pairs = (k + 1) / 2;
    for (var q = 0; q < pairs; q++) {
        let v = sh_fourier_pair(i, j, q);
        // Slot 2q (slot 0's imaginary part is zero), then slot 2q + 1 (zero past K).
        sum += vec2<f32>(v.x * ea.x - v.y * ea.y, v.x * eb.x - v.y * eb.y);
        ea = vec2<f32>(ea.x * ra.x - ea.y * ra.y, ea.y * ra.x + ea.x * ra.y);
        eb = vec2<f32>(eb.x * rb.x - eb.y * rb.y, eb.y * rb.x + eb.x * rb.y);
        sum += vec2<f32>(v.z * ea.x - v.w * ea.y, v.z * eb.x - v.w * eb.y);
        ea = vec2<f32>(ea.x * ra.x - ea.y * ra.y, ea.y * ra.x + ea.x * ra.y);
        eb = vec2<f32>(eb.x * rb.x - eb.y * rb.y, eb.y * rb.x + eb.x * rb.y);
    }
    return sum;
}

// α(θ) = Σ Re c_k cos kθ − Im c_k sin kθ (degrees): one sin/cos, then rotations. A constant
// trip count over all 32 slots (zero past the tile's k): with the loop bounded by k, lavapipe
// miscompiled the exact model's strips (mean 0.005 off the CPU's, constant model unaffected).
fn sh_series(coef: ptr<function, ShCoef>, theta: f32) -> f32 {
    let c1 = cos(theta);
    let s1 = sin(theta);
    var cs = 1.0;
    var sn = 0.0;
    var sum = (*coef)[0].x;
    for (var i = 1; i < SH_MAX_K; i++) {
        let nc = cs * c1 - sn * s1;
        sn = sn * c1 + cs * s1;
        cs = nc;
        let c = (*coef)[i];
        sum += c.x * cs - c.y * sn;
    }
    return sum;
}

fn sh_half_chord_integral(x_: f32) -> f32 {
    let x = clamp(x_, -1.0, 1.0);
    return 0.5 * (x * sqrt(max(1.0 - x * x, 0.0)) + asin(x));
}

// Area of the part of the unit disc with a ≤ x ≤ b and y ≥ c.
fn sh_strip_area_above(a_: f32, b_: f32, c_: f32) -> f32 {
    let a = clamp(a_, -1.0, 1.0);
    let b = clamp(b_, -1.0, 1.0);
    if b <= a {
        return 0.0;
    }
    var c = c_;
    var flip = false;
    if c < 0.0 {
        c = -c;
        flip = true;
    }
    var above = 0.0;
    if c < 1.0 {
        let xc = sqrt(1.0 - c * c);
        let lo = max(a, -xc);
        let hi = min(b, xc);
        if hi > lo {
            above = max(sh_half_chord_integral(hi) - sh_half_chord_integral(lo) - c * (hi - lo), 0.0);
        }
    }
    if flip {
        let whole = 2.0 * (sh_half_chord_integral(b) - sh_half_chord_integral(a));
        return max(whole - above, 0.0);
    }
    return above;
}

struct ShDisc {
    up: vec3<f32>,
    s: vec3<f32>,
    eh: vec3<f32>,
    ev: vec3<f32>,
    tan_r: f32,
    floor_deg: f32,
}

// Elevation of disc point (x, y) above the horizon, degrees.
fn sh_disc_g(coef: ptr<function, ShCoef>, d: ShDisc, x: f32, y: f32) -> f32 {
    let dir = normalize(d.s + d.tan_r * (x * d.eh + y * d.ev));
    let hor = clamp(max(sh_series(coef, sh_plane_azimuth(d.up, dir)), d.floor_deg), -90.0, 90.0);
    return sh_elevation_deg(d.up, dir) - hor;
}

// The horizon (degrees) from a series value: floored, clamped as the CPU's lookup.
fn sh_horizon(series: f32, floor_deg: f32) -> f32 {
    return clamp(max(series, floor_deg), -90.0, 90.0);
}

fn sh_fourier(p: vec2<i32>, h0: f32, up: vec3<f32>) -> f32 {
    let prm = shadow_params;
    let ti = p.x - prm.rect.x;
    let tj = p.y - prm.rect.y;
    let s = normalize(prm.sun.xyz);
    let r_deg = prm.sun.w;
    let floor_deg = sh_floor_deg(h0);
    let el = sh_elevation_deg(up, s);
    var d: ShDisc;
    d.up = up;
    d.s = s;
    d.floor_deg = floor_deg;
    let c = cross(s, up);
    if dot(c, c) > 1e-30 {
        d.eh = normalize(c);
    } else {
        // The zenith: any horizontal axis does.
        d.eh = normalize(cross(up, prm.face_u.xyz));
    }
    d.ev = normalize(cross(d.eh, s));
    d.tan_r = tan(r_deg / SH_DEG);
    let phi0 = sh_plane_azimuth(up, cross(up, d.eh));
    let model = prm.method.y;
    if r_deg <= 0.0 || model == 0 {
        // A point sun, or the constant model (Max 1988): the horizon at the sun centre's
        // azimuth held across the disc. The series once: O(K).
        let a0 = sh_horizon(sh_series_at(ti, tj, phi0, phi0).x, floor_deg);
        if r_deg <= 0.0 {
            if el > a0 {
                return 1.0;
            }
            if el < a0 {
                return 0.0;
            }
            return 0.5;
        }
        return sh_segment_fraction((a0 - el) / r_deg);
    }
    if model == 1 {
        // segment: the horizon linear between the disc's left and right rims; the lit part is
        // the disc above the chord through the two crossings. The series twice: O(K).
        let dl = normalize(s - d.tan_r * d.eh);
        let dr = normalize(s + d.tan_r * d.eh);
        let a = sh_series_at(ti, tj, sh_plane_azimuth(up, dl), sh_plane_azimuth(up, dr));
        let yl = sh_horizon(a.x, floor_deg) - sh_elevation_deg(up, dl);
        let yr = sh_horizon(a.y, floor_deg) - sh_elevation_deg(up, dr);
        let m = 0.5 * (yl + yr);
        let kk = 0.5 * (yr - yl);
        return clamp(sh_segment_fraction(m / sqrt(r_deg * r_deg + kk * kk)), 0.0, 1.0);
    }
    var coef: ShCoef;
    sh_fourier_coefficients(&coef, ti, tj);
    if model == 2 {
        // slices: 8 strips, the horizon at each strip's middle, each strip's exact area.
        var lit_s = 0.0;
        var whole = 0;
        for (var i = 0; i < 8; i++) {
            let a = -1.0 + 0.25 * f32(i);
            let b = a + 0.25;
            let c = -sh_disc_g(&coef, d, 0.5 * (a + b), 0.0) / r_deg;
            if c <= -1.0 {
                whole += 1;
            }
            lit_s += sh_strip_area_above(a, b, c);
        }
        if whole == 8 {
            return 1.0;
        }
        return clamp(lit_s / SH_PI, 0.0, 1.0);
    }
    let a0 = sh_horizon(sh_series(&coef, phi0), floor_deg);
    // A cheap answer where the horizon cannot cross the disc: |α'| ≤ Σ k|c_k| bounds its
    // change over the disc's azimuths (from 8 rim points, with 50 % to spare).
    if el + r_deg < 89.0 {
        var lip = 0.0;
        for (var i = 1; i < SH_MAX_K; i++) {
            lip += f32(i) * length(coef[i]);
        }
        var span = 0.0;
        for (var i = 0; i < 8; i++) {
            let th = SH_TAU * f32(i) / 8.0;
            let dir = normalize(s + d.tan_r * (cos(th) * d.eh + sin(th) * d.ev));
            var off = sh_plane_azimuth(up, dir) - phi0;
            if off > SH_PI {
                off -= SH_TAU;
            } else if off < -SH_PI {
                off += SH_TAU;
            }
            span = max(span, abs(off));
        }
        let reach = lip * (1.5 * span + 1e-4);
        if max(a0 + reach, floor_deg) < el - r_deg - 1e-3 {
            return 1.0;
        }
        if max(a0 - reach, floor_deg) > el + r_deg + 1e-3 {
            return 0.0;
        }
    }
    var lit = 0.0;
    let wdt = 2.0 / f32(SH_STRIPS);
    for (var i = 0; i < SH_STRIPS; i++) {
        let a = -1.0 + wdt * f32(i);
        let b = a + wdt;
        let x = 0.5 * (a + b);
        let h = sqrt(max(1.0 - x * x, 0.0));
        let lit_b = sh_disc_g(&coef, d, x, -h) > 0.0;
        let lit_t = sh_disc_g(&coef, d, x, h) > 0.0;
        if lit_b == lit_t {
            if lit_b {
                lit += sh_strip_area_above(a, b, -1.0);
            }
        } else {
            // One crossing in (−h, h): bisect for it (to f32's resolution), keeping `lo` on
            // the bottom's side.
            var lo = -h;
            var hi = h;
            for (var it = 0; it < 24; it++) {
                let mid = 0.5 * (lo + hi);
                if (sh_disc_g(&coef, d, x, mid) > 0.0) == lit_b {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let above = sh_strip_area_above(a, b, 0.5 * (lo + hi));
            if lit_t {
                lit += above;
            } else {
                lit += sh_strip_area_above(a, b, -1.0) - above;
            }
        }
    }
    return clamp(lit / SH_PI, 0.0, 1.0);
}

// ---------------------------------------------------------------------------------------------

// Lit fraction of the sun's disc at raster texel p: [0, 1], negative over no data.
fn shadow_lit(p: vec2<i32>) -> f32 {
    let prm = shadow_params;
    let h0 = sh_height(p.x, p.y);
    if !sh_valid(h0) {
        return -1.0;
    }
    let up = normalize(sh_plane_point(p.x, p.y));
    let method = prm.method.x;
    if method < 0 {
        // The tile holds no data for the method set.
        return -2.0;
    }
    if method == 3 {
        return sh_fourier(p, h0, up);
    }
    let s = normalize(prm.sun.xyz);
    let el = sh_elevation_deg(up, s);
    let phi = sh_plane_azimuth(up, s);
    let r = prm.sun.w;
    let floor_deg = sh_floor_deg(h0);
    if method == 2 {
        if el <= floor_deg {
            return 0.0;
        }
        let ray = sh_ray(p.x, p.y, h0, phi);
        if sh_extrema_dark(ray, p.x, p.y, phi, sh_tan_deg(el)) {
            return 0.0;
        }
        return 1.0;
    }
    if el + r <= floor_deg {
        return 0.0;
    }
    let lo = sh_tan_deg(el - r);
    let hi = sh_tan_deg(el + r);
    let ray = sh_ray(p.x, p.y, h0, phi);
    var a = SH_NEG;
    if method == 1 {
        a = sh_uniform(ray, prm.method.y, lo);
    } else if method == 4 {
        a = sh_extrema_soft(ray, p.x, p.y, phi, lo, hi);
    } else {
        a = sh_dp(ray, p.x, p.y, phi, lo, hi, method == 5);
    }
    return sh_occlusion(a, floor_deg, el, r);
}
