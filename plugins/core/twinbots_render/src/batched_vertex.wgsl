enable clip_distances;
// The vertex stage of batched frames (batch.rs): each vertex of a surface instance through its
// arena's camera into the arena's tile of the frame, clipped to the tile (the camera's view:
// no fragment is shaded outside it, none spills into a neighbour's tile).
#import bevy_pbr::forward_io::Vertex
#import bevy_pbr::mesh_functions

// As in lambert.wgsl.
struct ArenaView {
    clip_from_world: mat4x4<f32>,
    tile: vec4<f32>,
    eye: vec4<f32>,
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

@group(#{MATERIAL_BIND_GROUP}) @binding(3) var<storage, read> arena_views: array<ArenaView>;
@group(#{MATERIAL_BIND_GROUP}) @binding(4) var<storage, read> surfaces: array<SurfaceRecord>;

// lambert.wgsl's LambertVertexOutput (BATCHED), and the distances to the tile's edges.
struct ClippedVertexOutput {
    @builtin(position) position: vec4<f32>,
    @location(0) world_position: vec4<f32>,
    @location(1) world_normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) @interpolate(flat) tag: u32,
    @builtin(clip_distances) clip_distances: array<f32, 4>,
}

@vertex
fn vertex(vertex: Vertex) -> ClippedVertexOutput {
    var out: ClippedVertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(vertex.instance_index);
    out.world_position = mesh_functions::mesh_position_local_to_world(world_from_local, vec4(vertex.position, 1.0));
    out.world_normal = mesh_functions::mesh_normal_local_to_world(vertex.normal, vertex.instance_index);
    out.tag = mesh_functions::get_tag(vertex.instance_index);
    // Field by field: a whole ArenaView copied per vertex costs lavapipe dearly.
    let arena = surfaces[out.tag].arena;
    let clip = arena_views[arena].clip_from_world * out.world_position;
    let tile = arena_views[arena].tile;
    // Inside the camera's view: −w ≤ x, y ≤ w in its own clip space.
    out.clip_distances = array(clip.w + clip.x, clip.w - clip.x, clip.w + clip.y, clip.w - clip.y);
    out.position = vec4(clip.xy * tile.xy + tile.zw * clip.w, clip.zw);
#ifdef VERTEX_UVS_A
    out.uv = vertex.uv;
#else
    out.uv = vec2(0.0);
#endif
    return out;
}
