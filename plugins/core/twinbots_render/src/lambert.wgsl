// Diffuse (Lambert) shading: the scene's directional lights, with their colours and
// intensities, over the ambient light; the albedo is a colour, a pattern laid out in metres
// (the mesh's UVs are metres, see scene.rs) or a tiled image. PATTERN (0 plain, 1 checker,
// 2 noise, 3 gradient, 4 image) and LIGHTS (how many) are compiled in: see shading.rs.
#import bevy_pbr::forward_io::VertexOutput
#import bevy_pbr::mesh_view_bindings::{lights, view}
#import bevy_pbr::shadows::fetch_directional_shadow

struct LambertMaterial {
    // Linear RGB(A).
    color: vec4<f32>,
    color2: vec4<f32>,
    kind: u32,
    size: f32,
    specular: f32,
}

// Blinn-Phong's exponent: a highlight about 25° wide.
const SHININESS: f32 = 32.0;

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> material: LambertMaterial;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var image: texture_2d<f32>;
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var image_sampler: sampler;

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

fn albedo(uv: vec2<f32>) -> vec3<f32> {
    let p = uv / material.size;
    let a = material.color.rgb;
    let b = material.color2.rgb;
#if PATTERN == 1
    let cell = floor(p);
    return select(a, b, (i32(cell.x) + i32(cell.y)) % 2 != 0);
#else if PATTERN == 2
    return mix(a, b, value_noise(p));
#else if PATTERN == 3
    return mix(a, b, abs(fract(p.x * 0.5) * 2.0 - 1.0));
#else if PATTERN == 4
    return a * textureSample(image, image_sampler, p).rgb;
#else
    return a;
#endif
}

// What directional light `i` adds on a surface facing `normal` seen from `to_eye`: diffuse
// (`.diffuse`, times the albedo later) and the highlight (`.highlight`); in its shadow map's
// shadow, with SHADOWS, nothing.
struct Lit {
    diffuse: vec3<f32>,
    highlight: vec3<f32>,
}

fn sun(i: u32, normal: vec3<f32>, to_eye: vec3<f32>, in: VertexOutput) -> Lit {
    let towards = lights.directional_lights[i].direction_to_light;
    let color = lights.directional_lights[i].color.rgb;
    let facing = max(dot(normal, towards), 0.0);
    var lit = Lit(color * facing, vec3(0.0));
#ifdef SPECULAR
    if facing > 0.0 {
        lit.highlight = color * pow(max(dot(normal, normalize(towards + to_eye)), 0.0), SHININESS);
    }
#endif
#ifdef SHADOWS
    let view_z = dot(vec4(view.view_from_world[0].z, view.view_from_world[1].z, view.view_from_world[2].z, view.view_from_world[3].z), in.world_position);
    let shadow = fetch_directional_shadow(i, in.world_position, normal, view_z, in.position.xy);
    lit.diffuse *= shadow;
    lit.highlight *= shadow;
#endif
    return lit;
}

fn add(a: Lit, b: Lit) -> Lit {
    return Lit(a.diffuse + b.diffuse, a.highlight + b.highlight);
}

@fragment
fn fragment(in: VertexOutput) -> @location(0) vec4<f32> {
    let normal = normalize(in.world_normal);
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
#ifdef VERTEX_UVS_A
    let uv = in.uv;
#else
    let uv = vec2(0.0);
#endif
    return vec4(albedo(uv) * light.diffuse + material.specular * light.highlight, 1.0);
}
