// Composite: the rendered frame onto the window's surface (or a screenshot texture), with the
// status line (a one-channel text mask) in the top-left corner on a dark band.

struct Overlay {
    // x, y: text mask size in pixels; z: 1 to draw the overlay; w: unused.
    size: vec4<f32>,
};

@group(0) @binding(0) var frame_tex: texture_2d<f32>;
@group(0) @binding(1) var text_tex: texture_2d<f32>;
@group(0) @binding(2) var<uniform> overlay: Overlay;

@vertex
fn vs_main(@builtin(vertex_index) k: u32) -> @builtin(position) vec4<f32> {
    // One triangle that covers the screen.
    let x = f32((k << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(k & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let px = vec2<i32>(floor(p.xy));
    let dims = vec2<i32>(textureDimensions(frame_tex, 0));
    var c = textureLoad(frame_tex, clamp(px, vec2<i32>(0), dims - vec2<i32>(1)), 0).rgb;
    if (overlay.size.z > 0.5) {
        let ts = vec2<i32>(overlay.size.xy);
        if (px.x < ts.x && px.y < ts.y) {
            let a = textureLoad(text_tex, px, 0).r;
            c = mix(c * 0.35, vec3<f32>(1.0, 0.93, 0.55), a);
        }
    }
    return vec4<f32>(c, 1.0);
}
