//! The scene: every link's visuals as Foxglove primitives, locked to the link's frame.

use bevy::prelude::*;
use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, Point3, Pose as FgPose, Quaternion, SceneEntity, SpherePrimitive,
    Timestamp, TriangleListPrimitive, Vector3,
};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::Shape;
use twinbots_sim::{InArena, Link, Visuals};

use crate::MAX_SCENE_TRIANGLES;

fn fg_pose(pose: &Pose) -> FgPose {
    let (t, r) = (pose.translation, pose.rotation);
    FgPose {
        position: Some(Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 }),
        orientation: Some(Quaternion { x: r.x as f64, y: r.y as f64, z: r.z as f64, w: r.w as f64 }),
    }
}

/// Every link's visuals in the arenas `names` names, each in its own frame (`<name>/<link>`,
/// locked to it, so `/tf` moves them); coloured `tint` instead of their own if given.
pub(crate) fn entities(
    world: &mut World,
    names: &[(Entity, &str)],
    stamp: Timestamp,
    tint: Option<[f32; 4]>,
) -> Vec<SceneEntity> {
    let name_of = |arena: Entity| names.iter().find(|(a, _)| *a == arena).map(|(_, n)| *n);
    let mut entities = Vec::new();
    for (link, visuals, in_arena) in world.query::<(&Link, &Visuals, &InArena)>().iter(world) {
        let Some(name) = name_of(in_arena.0) else { continue };
        let frame_id = format!("{name}/{}", link.name);
        let mut entity = SceneEntity {
            timestamp: Some(stamp),
            frame_id: frame_id.clone(),
            id: frame_id,
            frame_locked: true,
            ..Default::default()
        };
        for visual in &visuals.0 {
            let [r, g, b, a] = tint.unwrap_or(visual.rgba).map(f64::from);
            let color = Some(Color { r, g, b, a });
            let pose = Some(fg_pose(&visual.geometry.origin));
            match &visual.geometry.shape {
                Shape::Box { half_extents: h } => entity.cubes.push(CubePrimitive {
                    pose,
                    size: Some(Vector3 { x: 2.0 * h.x as f64, y: 2.0 * h.y as f64, z: 2.0 * h.z as f64 }),
                    color,
                }),
                Shape::Cylinder { radius, length } => entity.cylinders.push(CylinderPrimitive {
                    pose,
                    size: Some(Vector3 { x: 2.0 * *radius as f64, y: 2.0 * *radius as f64, z: *length as f64 }),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color,
                }),
                Shape::Sphere { radius } => {
                    let d = 2.0 * *radius as f64;
                    entity.spheres.push(SpherePrimitive { pose, size: Some(Vector3 { x: d, y: d, z: d }), color })
                }
                Shape::Mesh(mesh) => {
                    let points = mesh_points(&mesh.vertices, &mesh.triangles);
                    entity.triangles.push(TriangleListPrimitive { pose, points, color, ..Default::default() });
                }
            }
        }
        entities.push(entity);
    }
    entities
}

/// A mesh's triangles as a flat point list (three per triangle); one over
/// [`MAX_SCENE_TRIANGLES`] as its convex hull's.
fn mesh_points(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Point3> {
    let point = |v: Vec3| Point3 { x: v.x as f64, y: v.y as f64, z: v.z as f64 };
    if triangles.len() <= MAX_SCENE_TRIANGLES {
        return triangles.iter().flat_map(|t| t.map(|i| point(vertices[i as usize]))).collect();
    }
    let points: Vec<_> = vertices.iter().map(|v| twinbots_sim::rapier::math::Vector::new(v.x, v.y, v.z)).collect();
    let (hull, faces) = twinbots_sim::rapier::parry::transformation::convex_hull(&points);
    faces
        .iter()
        .flat_map(|f| f.map(|i| point(Vec3::new(hull[i as usize].x, hull[i as usize].y, hull[i as usize].z))))
        .collect()
}
