// Terrain: displaced cube-sphere tile meshes, drawn relative to the eye, with Lambert shading,
// albedo when the tileset has it, and the soft shadow of the selected method (`shadow_lit`,
// declared by the shadow module's WGSL that follows this file, in @group(1)).
//
// Three targets: the shaded colour, the lit fraction of the nearest tile texel (the bits of
// an f32 in R32Uint, which every backend can render; negative: no shadow data) and which
// texel it was (tile index + 1, i | j << 16) for validating the GPU against the CPU at
// exactly those texels.

struct Frame {
    // Eye-relative body frame → clip: the view rotation and a reversed-Z infinite perspective.
    view_proj: mat4x4<f32>,
    // Unit direction towards the sun's centre, body frame.
    sun_dir: vec4<f32>,
    // x: ambient term, y: 1 to show the shadow, 0 for Lambert only, z, w: unused.
    params: vec4<f32>,
};

struct Tile {
    // The tile's centre minus the eye (m, body frame), computed in f64 on the CPU.
    offset: vec4<f32>,
    // x: tile index in this frame, y: interior pixels per side n, z, w: raster position of
    // interior texel (0, 0) in the shadow context (`TileShadow::rect`).
    info: vec4<i32>,
    // x: 1 when the albedo texture holds the tileset's albedo, y: halo, z: stored size.
    albedo: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;

@group(2) @binding(0) var<uniform> tile: Tile;
@group(2) @binding(1) var normals: texture_2d<f32>;
@group(2) @binding(2) var albedo_tex: texture_2d<f32>;
@group(2) @binding(3) var linear_clamp: sampler;

struct VsIn {
    @location(0) pos: vec3<f32>,
    @location(1) ij: vec2<f32>,
};

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) ij: vec2<f32>,
};

@vertex
fn vs_main(v: VsIn) -> VsOut {
    var out: VsOut;
    out.clip = frame.view_proj * vec4<f32>(v.pos + tile.offset.xyz, 1.0);
    out.ij = v.ij;
    return out;
}

struct FsOut {
    @location(0) colour: vec4<f32>,
    @location(1) lit: u32,
    @location(2) id: vec2<u32>,
};

@fragment
fn fs_main(in: VsOut) -> FsOut {
    let n = tile.info.y;
    let nf = f32(n);
    // The nearest interior texel: its shadow is the one shown and validated.
    let t = clamp(vec2<i32>(floor(in.ij + vec2<f32>(0.5))), vec2<i32>(0), vec2<i32>(n - 1));
    // The normals texture has a one-texel border: texel (i, j) is at (i + 1, j + 1).
    if (textureLoad(normals, t + vec2<i32>(1), 0).w < 0.5) {
        discard;
    }
    var lit = 1.0;
    if (frame.params.y > 0.5) {
        lit = shadow_lit(vec2<i32>(tile.info.z + t.x, tile.info.w + t.y));
    }
    let nrm_s = textureSampleLevel(normals, linear_clamp, (in.ij + vec2<f32>(1.5)) / (nf + 2.0), 0.0);
    let nrm = normalize(nrm_s.xyz);
    let lambert = max(dot(nrm, frame.sun_dir.xyz), 0.0);
    var base = vec3<f32>(0.72);
    if (tile.albedo.x > 0.5) {
        let st = (in.ij + vec2<f32>(tile.albedo.y + 0.5)) / tile.albedo.z;
        base = textureSampleLevel(albedo_tex, linear_clamp, st, 0.0).rgb;
    }
    let ambient = frame.params.x;
    var out: FsOut;
    if (lit < 0.0) {
        // No data in the shadow raster: neither lit nor shadowed (the CPU images' dark blue).
        out.colour = vec4<f32>(0.021, 0.045, 0.156, 1.0);
    } else {
        out.colour = vec4<f32>(base * (ambient + (1.0 - ambient) * lambert * lit), 1.0);
    }
    out.lit = bitcast<u32>(lit);
    out.id = vec2<u32>(u32(tile.info.x + 1), u32(t.x) | (u32(t.y) << 16u));
    return out;
}
