// objslam renderer. One pass writes the lit colour, the instance id, the class id and the
// metric z-depth to four targets, so the masks are pixel-exact and aligned with the colour.

struct Frame {
    // Clip from world: the pinhole intrinsics folded into a projection (see lib.rs).
    clip_from_world: mat4x4<f32>,
    // Camera (optical frame) from world, for the metric z-depth.
    camera_from_world: mat4x4<f32>,
    // Direction the sunlight travels (unit, world).
    sun_direction: vec4<f32>,
    sun_colour: vec4<f32>,
    ambient: vec4<f32>,
    // x: exposure.
    params: vec4<f32>,
    // Camera position in the world (xyz).
    eye: vec4<f32>,
};

struct Instance {
    world_from_model: mat4x4<f32>,
    // Inverse transpose of the upper 3x3 (columns), so scaled models keep correct normals.
    normal_from_model: mat3x3<f32>,
    // x: instance id, y: class id.
    ids: vec4<u32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(1) @binding(0) var<uniform> instance: Instance;
@group(2) @binding(0) var albedo: texture_2d<f32>;
@group(2) @binding(1) var albedo_sampler: sampler;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) uv: vec2<f32>,
    // Camera-frame z: affine in the position, so perspective-correct interpolation is exact.
    @location(2) z_m: f32,
    @location(3) world: vec3<f32>,
};

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    let world = instance.world_from_model * vec4<f32>(v.position, 1.0);
    var out: VertexOut;
    out.clip = frame.clip_from_world * world;
    out.normal = instance.normal_from_model * v.normal;
    out.uv = v.uv;
    out.z_m = (frame.camera_from_world * world).z;
    out.world = world.xyz;
    return out;
}

struct FragmentOut {
    @location(0) colour: vec4<f32>,
    // Instance id << 8 | class id: one target for both (see IDS_FORMAT in lib.rs).
    @location(1) ids: u32,
    // The f32 z-depth's bits (see DEPTH_OUT_FORMAT in lib.rs). Lines ending in "depth
    // target" are left out when the renderer is made without depth.
    @location(2) z_bits: u32, // depth target
};

/// Lit colour and ids of a fragment whose (unnormalised) normal `normal` faces the camera.
fn shade(in: VertexOut, normal: vec3<f32>) -> FragmentOut {
    let n = normalize(normal);
    let base = textureSample(albedo, albedo_sampler, in.uv).rgb;
    let sun = max(dot(n, -frame.sun_direction.xyz), 0.0);
    // Hemispheric sky term: full ambient facing up, 40 % facing down.
    let sky = 0.7 + 0.3 * n.z;
    let light = frame.ambient.rgb * sky + frame.sun_colour.rgb * sun;
    var out: FragmentOut;
    out.colour = vec4<f32>(base * light * frame.params.x, 1.0);
    out.ids = (instance.ids.x << 8u) | (instance.ids.y & 0xffu);
    out.z_bits = bitcast<u32>(in.z_m); // depth target
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    // Light the side that is seen, whatever the winding: open meshes (trunks without caps)
    // show their inside. The facet's own normal, turned towards the camera, decides; it is
    // within a few degrees of the interpolated normal on the outside, opposite inside.
    var n = in.normal;
    var facet = cross(dpdx(in.world), dpdy(in.world));
    if dot(facet, frame.eye.xyz - in.world) < 0.0 {
        facet = -facet;
    }
    if dot(n, facet) < 0.0 {
        n = -n;
    }
    return shade(in, n);
}

/// For meshes drawn with back faces culled: what is drawn is seen from outside, where the
/// normals point, so the facet test of `fs_main` is not needed.
@fragment
fn fs_front(in: VertexOut) -> FragmentOut {
    return shade(in, in.normal);
}
