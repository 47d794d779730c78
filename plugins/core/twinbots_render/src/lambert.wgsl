// Diffuse (Lambert) shading: the scene's directional lights, with their colours and
// intensities, over the ambient light; the albedo is a colour, a pattern laid out in metres
// (the mesh's UVs are metres, see scene.rs) or a tiled image. PATTERN (0 plain, 1 checker,
// 2 noise, 3 gradient, 4 image) and LIGHTS (how many) are compiled in: see shading.rs.
// BATCHED (batch.rs): the vertex stage is batched_vertex.wgsl; the surface is the instance's
// SurfaceRecord (its pattern branched on), the lights its arena's ArenaView (looped over).
#import bevy_pbr::forward_io::Vertex
#import bevy_pbr::mesh_functions
#import bevy_pbr::mesh_view_bindings::{lights, view}
#import bevy_pbr::shadows::fetch_directional_shadow
#import bevy_pbr::view_transformations::position_world_to_clip

// Blinn-Phong's exponent: a highlight about 25° wide.
const SHININESS: f32 = 32.0;

// The material's bindings and batched frames' buffers, as in batched_vertex.wgsl (naga_oil
// cannot share them through an import: it mangles the structs' fields).
struct LambertMaterial {
    // Linear RGB(A).
    color: vec4<f32>,
    color2: vec4<f32>,
    kind: u32,
    size: f32,
    specular: f32,
}

struct ArenaView {
    clip_from_world: mat4x4<f32>,
    tile: vec4<f32>,
    eye: vec4<f32>,
    // .w: how many lights.
    ambient: vec4<f32>,
    light_directions: array<vec4<f32>, 10>,
    light_colors: array<vec4<f32>, 10>,
}

struct SurfaceRecord {
    color: vec4<f32>,
    color2: vec4<f32>,
    kind: u32,
    size: f32,
    specular: f32,
    arena: u32,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> material: LambertMaterial;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var image: texture_2d<f32>;
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var image_sampler: sampler;
@group(#{MATERIAL_BIND_GROUP}) @binding(3) var<storage, read> arena_views: array<ArenaView>;
@group(#{MATERIAL_BIND_GROUP}) @binding(4) var<storage, read> surfaces: array<SurfaceRecord>;

struct LambertVertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) world_position: vec4<f32>,
    @location(1) world_normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
#ifdef BATCHED
    // As batched_vertex.wgsl writes it: the instance's MeshTag (its SurfaceRecord).
    @location(3) @interpolate(flat) tag: u32,
#endif
}

// Bevy's mesh vertex stage without skinning or morphs.
@vertex
fn vertex(vertex: Vertex) -> LambertVertexOutput {
    var out: LambertVertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(vertex.instance_index);
    out.world_position = mesh_functions::mesh_position_local_to_world(world_from_local, vec4(vertex.position, 1.0));
    out.world_normal = mesh_functions::mesh_normal_local_to_world(vertex.normal, vertex.instance_index);
    out.position = position_world_to_clip(out.world_position.xyz);
#ifdef VERTEX_UVS_A
    out.uv = vertex.uv;
#else
    out.uv = vec2(0.0);
#endif
    return out;
}

fn hash(p: vec2<f32>) -> f32 {
    return fract(sin(dot(p, vec2(127.1, 311.7))) * 43758.5453);
}

// Value noise in [0, 1]: smooth between random values at integer points.
fn value_noise(p: vec2<f32>) -> f32 {
    let i = floor(p);
    let f = fract(p);
    let u = f * f * (3.0 - 2.0 * f);
    let a = mix(hash(i), hash(i + vec2(1.0, 0.0)), u.x);
    let b = mix(hash(i + vec2(0.0, 1.0)), hash(i + vec2(1.0, 1.0)), u.x);
    return mix(a, b, u.y);
}

fn checker(a: vec3<f32>, b: vec3<f32>, p: vec2<f32>) -> vec3<f32> {
    let cell = floor(p);
    return select(a, b, (i32(cell.x) + i32(cell.y)) % 2 != 0);
}

fn gradient(a: vec3<f32>, b: vec3<f32>, p: vec2<f32>) -> vec3<f32> {
    return mix(a, b, abs(fract(p.x * 0.5) * 2.0 - 1.0));
}

// The material's albedo, its pattern compiled in.
fn albedo(uv: vec2<f32>) -> vec3<f32> {
    let p = uv / material.size;
    let a = material.color.rgb;
    let b = material.color2.rgb;
#if PATTERN == 1
    return checker(a, b, p);
#else if PATTERN == 2
    return mix(a, b, value_noise(p));
#else if PATTERN == 3
    return gradient(a, b, p);
#else if PATTERN == 4
    return a * textureSample(image, image_sampler, p).rgb;
#else
    return a;
#endif
}

// Surface record `tag`'s albedo, its pattern branched on (the image level 0: no derivatives in
// a branch).
fn record_albedo(tag: u32, uv: vec2<f32>) -> vec3<f32> {
    let a = surfaces[tag].color.rgb;
    let kind = surfaces[tag].kind;
    if kind == 0u {
        return a;
    }
    let b = surfaces[tag].color2.rgb;
    let p = uv / surfaces[tag].size;
    switch kind {
        case 1u: { return checker(a, b, p); }
        case 2u: { return mix(a, b, value_noise(p)); }
        case 3u: { return gradient(a, b, p); }
        default: { return a * textureSampleLevel(image, image_sampler, p, 0.0).rgb; }
    }
}

// What a directional light (towards it, its colour) adds on a surface facing `normal` seen
// from `to_eye`: diffuse (`.diffuse`, times the albedo later) and the highlight (`.highlight`).
struct Lit {
    diffuse: vec3<f32>,
    highlight: vec3<f32>,
}

fn add(a: Lit, b: Lit) -> Lit {
    return Lit(a.diffuse + b.diffuse, a.highlight + b.highlight);
}

fn directional(towards: vec3<f32>, color: vec3<f32>, normal: vec3<f32>, to_eye: vec3<f32>, specular: bool) -> Lit {
    let facing = max(dot(normal, towards), 0.0);
    var lit = Lit(color * facing, vec3(0.0));
    if specular && facing > 0.0 {
        lit.highlight = color * pow(max(dot(normal, normalize(towards + to_eye)), 0.0), SHININESS);
    }
    return lit;
}

// Bevy's directional light `i`; in its shadow map's shadow, with SHADOWS, nothing.
fn sun(i: u32, normal: vec3<f32>, to_eye: vec3<f32>, in: LambertVertexOutput) -> Lit {
#ifdef SPECULAR
    let specular = true;
#else
    let specular = false;
#endif
    var lit = directional(lights.directional_lights[i].direction_to_light, lights.directional_lights[i].color.rgb, normal, to_eye, specular);
#ifdef SHADOWS
    let view_z = dot(vec4(view.view_from_world[0].z, view.view_from_world[1].z, view.view_from_world[2].z, view.view_from_world[3].z), in.world_position);
    let shadow = fetch_directional_shadow(i, in.world_position, normal, view_z, in.position.xy);
    lit.diffuse *= shadow;
    lit.highlight *= shadow;
#endif
    return lit;
}

@fragment
fn fragment(in: LambertVertexOutput) -> @location(0) vec4<f32> {
    let normal = normalize(in.world_normal);
#ifdef BATCHED
    // Field by field: a whole ArenaView copied per pixel costs lavapipe dearly.
    let arena = surfaces[in.tag].arena;
    let specular = surfaces[in.tag].specular;
    let to_eye = normalize(arena_views[arena].eye.xyz - in.world_position.xyz);
    let ambient = arena_views[arena].ambient;
    var light = Lit(ambient.rgb, vec3(0.0));
    for (var i = 0u; i < u32(ambient.w); i++) {
        light = add(light, directional(arena_views[arena].light_directions[i].xyz, arena_views[arena].light_colors[i].rgb, normal, to_eye, specular > 0.0));
    }
    return vec4(record_albedo(in.tag, in.uv) * light.diffuse + specular * light.highlight, 1.0);
#else
    let to_eye = normalize(view.world_position - in.world_position.xyz);
    var light = Lit(lights.ambient_color.rgb, vec3(0.0));
    // Constant indices, as many as the scene has lights (Look::MAX_LIGHTS at most).
#if LIGHTS > 0
    light = add(light, sun(0u, normal, to_eye, in));
#endif
#if LIGHTS > 1
    light = add(light, sun(1u, normal, to_eye, in));
#endif
#if LIGHTS > 2
    light = add(light, sun(2u, normal, to_eye, in));
#endif
#if LIGHTS > 3
    light = add(light, sun(3u, normal, to_eye, in));
#endif
#if LIGHTS > 4
    light = add(light, sun(4u, normal, to_eye, in));
#endif
#if LIGHTS > 5
    light = add(light, sun(5u, normal, to_eye, in));
#endif
#if LIGHTS > 6
    light = add(light, sun(6u, normal, to_eye, in));
#endif
#if LIGHTS > 7
    light = add(light, sun(7u, normal, to_eye, in));
#endif
#if LIGHTS > 8
    light = add(light, sun(8u, normal, to_eye, in));
#endif
#if LIGHTS > 9
    light = add(light, sun(9u, normal, to_eye, in));
#endif
    return vec4(albedo(in.uv) * light.diffuse + material.specular * light.highlight, 1.0);
#endif
}
