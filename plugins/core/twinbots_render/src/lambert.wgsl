// Diffuse (Lambert) shading: the scene's first directional light plus a constant ambient share.
// See shading.rs for why the twin is not drawn with Bevy's PBR material.
#import bevy_pbr::forward_io::VertexOutput
#import bevy_pbr::mesh_view_bindings::lights

struct LambertMaterial {
    // Linear RGB(A).
    color: vec4<f32>,
}

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> material: LambertMaterial;

// The share of a surface's colour seen where the sun does not reach it.
const AMBIENT: f32 = 0.4;

@fragment
fn fragment(in: VertexOutput) -> @location(0) vec4<f32> {
    let normal = normalize(in.world_normal);
    var sunlit = 0.0;
    if lights.n_directional_lights > 0u {
        sunlit = max(dot(normal, lights.directional_lights[0].direction_to_light), 0.0);
    }
    return vec4(material.color.rgb * (AMBIENT + (1.0 - AMBIENT) * sunlit), material.color.a);
}
