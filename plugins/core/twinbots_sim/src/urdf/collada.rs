//! Collada (`.dae`, 1.4 and 1.5) as robot vendors ship their visual meshes (UR's
//! `ur_description`, Franka's, Kinova's): the triangles of every geometry the visual scene
//! instances, through its nodes' transforms (`matrix`, `translate`, `rotate`, `scale`, nested
//! nodes, `instance_node`), scaled by `<unit meter>` and turned so that the file's `up_axis` is
//! the link's Z (as RViz and Gazebo show them). `triangles`, `polylist` and `polygons` are read
//! (polygons fanned into triangles); lines, materials and textures are not a twin's concern.
//!
//! Written over `roxmltree` (the URDF reader's XML parser) rather than a Collada crate: what a
//! twin needs is this subset, and a reader that validates the whole schema eagerly refuses a
//! vendor's file for an off-schema element it would never use.

use std::collections::HashMap;

use bevy::math::{Mat4, Quat, Vec3};
use roxmltree::{Document, Node};

/// Vertices and index triples (as `mesh::Triangles`).
type Triangles = (Vec<Vec3>, Vec<[u32; 3]>);

/// Reads the triangles of a Collada document, in metres, Z up.
/// `max_triangles` bounds the instances placed (checked as they are, not after).
pub fn read(text: &str, max_triangles: usize) -> Result<Triangles, String> {
    if let Some(line) = super::xml_depth::too_deep(text) {
        return Err(format!("line {line}: elements nest deeper than {} levels", super::xml_depth::MAX_XML_DEPTH));
    }
    let doc = Document::parse(text).map_err(|e| format!("not valid XML: {e}"))?;
    let root = doc.root_element();
    if root.tag_name().name() != "COLLADA" {
        return Err(format!("not a Collada document: its root element is <{}>", root.tag_name().name()));
    }
    let ids: HashMap<&str, Node> = root.descendants().filter_map(|n| n.attribute("id").map(|id| (id, n))).collect();
    let asset = child(root, "asset");
    let meter = match asset.and_then(|a| child(a, "unit")).and_then(|u| u.attribute("meter")) {
        Some(m) => m
            .trim()
            .parse::<f32>()
            .ok()
            .filter(|m| m.is_finite() && *m > 0.0)
            .ok_or_else(|| format!("<unit meter=\"{m}\">: not a positive number"))?,
        None => 1.0,
    };
    let up = asset.and_then(|a| child(a, "up_axis")).and_then(|u| u.text()).map(str::trim).unwrap_or("Y_UP");
    let turn = match up {
        "Z_UP" => Quat::IDENTITY,
        "Y_UP" => Quat::from_rotation_x(std::f32::consts::FRAC_PI_2),
        "X_UP" => Quat::from_rotation_y(-std::f32::consts::FRAC_PI_2),
        other => return Err(format!("<up_axis>{other}</up_axis>: not X_UP, Y_UP or Z_UP")),
    };
    let to_link = Mat4::from_rotation_translation(turn, Vec3::ZERO) * Mat4::from_scale(Vec3::splat(meter));
    let reader = Reader { ids: &ids, max_triangles };
    let mut out: Triangles = (Vec::new(), Vec::new());
    match visual_scene(root, &ids) {
        Some(scene) => {
            for node in children(scene, "node") {
                reader.node(node, to_link, &mut out, 0)?;
            }
        }
        // No scene to place them: every geometry as it is.
        None => {
            for geometry in root.descendants().filter(|n| is(*n, "geometry")) {
                reader.geometry(geometry, to_link, &mut out)?;
            }
        }
    }
    Ok(out)
}

struct Reader<'a, 'input> {
    ids: &'a HashMap<&'input str, Node<'input, 'input>>,
    max_triangles: usize,
}

/// Nodes nest at most this deep (a file that nests deeper is refused, not recursed into).
const MAX_DEPTH: usize = 64;

impl<'input> Reader<'_, 'input> {
    fn node(&self, node: Node<'input, 'input>, parent: Mat4, out: &mut Triangles, depth: usize) -> Result<(), String> {
        if depth > MAX_DEPTH {
            return Err(format!("nodes nested deeper than {MAX_DEPTH} (a loop of <instance_node>?)"));
        }
        // Instances multiply: nodes that each instance another twice, 64 deep, would ask for
        // 2⁶⁴ copies. The cap is checked as they are made.
        if out.1.len() > self.max_triangles {
            return Err(format!("more than {} triangles once its instances are placed", self.max_triangles));
        }
        let mut pose = parent;
        for t in node.children().filter(Node::is_element) {
            let name = t.tag_name().name();
            let v = || floats(t).map_err(|e| format!("<{name}> of node '{}': {e}", label(node)));
            pose *= match name {
                "matrix" => {
                    let m: [f32; 16] =
                        v()?.try_into().map_err(|_| format!("<matrix> of node '{}': not 16 numbers", label(node)))?;
                    // Collada writes matrices row by row; glam's are column-major.
                    Mat4::from_cols_array(&m).transpose()
                }
                "translate" => Mat4::from_translation(vec3(&v()?, name, node)?),
                "scale" => Mat4::from_scale(vec3(&v()?, name, node)?),
                "rotate" => {
                    let r = v()?;
                    let [x, y, z, degrees] = r[..] else {
                        return Err(format!("<rotate> of node '{}': not 4 numbers", label(node)));
                    };
                    let axis = Vec3::new(x, y, z);
                    if axis.length_squared() < 1e-12 {
                        Mat4::IDENTITY
                    } else {
                        Mat4::from_axis_angle(axis.normalize(), degrees.to_radians())
                    }
                }
                _ => continue,
            };
        }
        for t in node.children().filter(Node::is_element) {
            match t.tag_name().name() {
                "instance_geometry" => self.geometry(self.target(t, node)?, pose, out)?,
                "instance_node" => self.node(self.target(t, node)?, pose, out, depth + 1)?,
                "node" => self.node(t, pose, out, depth + 1)?,
                _ => {}
            }
        }
        Ok(())
    }

    /// The element an instance's `url="#id"` names.
    fn target(&self, instance: Node<'input, 'input>, node: Node) -> Result<Node<'input, 'input>, String> {
        let url = instance.attribute("url").unwrap_or("");
        let id = url.strip_prefix('#').ok_or_else(|| {
            format!(
                "<{}> of node '{}': url '{url}' is not a reference into this file",
                instance.tag_name().name(),
                label(node)
            )
        })?;
        self.ids
            .get(id)
            .copied()
            .ok_or_else(|| format!("node '{}' instances '#{id}', which the file lacks", label(node)))
    }

    /// A `<geometry>`'s triangles, placed by `pose`.
    fn geometry(&self, geometry: Node<'input, 'input>, pose: Mat4, out: &mut Triangles) -> Result<(), String> {
        let Some(mesh) = child(geometry, "mesh") else { return Ok(()) };
        let name = label(geometry);
        for primitive in mesh.children().filter(Node::is_element) {
            let kind = primitive.tag_name().name();
            if !matches!(kind, "triangles" | "polylist" | "polygons") {
                continue;
            }
            let at = |e: String| format!("geometry '{name}', <{kind}>: {e}");
            let inputs: Vec<Node> = children(primitive, "input").collect();
            let offset =
                |i: &Node| i.attribute("offset").unwrap_or("0").parse::<usize>().map_err(|e| at(e.to_string()));
            let mut stride = 1;
            for i in &inputs {
                stride = stride.max(offset(i)? + 1);
            }
            let Some(vertex) = inputs.iter().find(|i| i.attribute("semantic") == Some("VERTEX")) else {
                return Err(at("no VERTEX input".into()));
            };
            let vertex_offset = offset(vertex)?;
            let positions = self.positions(vertex).map_err(at)?;
            let base = out.0.len();
            out.0.extend(positions.iter().map(|p| pose.transform_point3(*p)));
            let count = positions.len();
            let corner = |p: &[usize], k: usize| -> Result<u32, String> {
                let i = *p.get(k * stride + vertex_offset).ok_or_else(|| at(format!("<p> ends within vertex {k}")))?;
                if i >= count {
                    return Err(at(format!("<p> names position {i} of {count}")));
                }
                Ok((base + i) as u32)
            };
            let polygons: Vec<(Vec<usize>, Vec<usize>)> = match kind {
                "triangles" => {
                    let p = indices(child(primitive, "p")).map_err(at)?;
                    let n = p.len() / stride / 3;
                    vec![(p, vec![3; n])]
                }
                "polylist" => {
                    let p = indices(child(primitive, "p")).map_err(at)?;
                    let vcount = indices(child(primitive, "vcount")).map_err(at)?;
                    vec![(p, vcount)]
                }
                _ => children(primitive, "p")
                    .map(|p| {
                        let p = indices(Some(p)).map_err(at)?;
                        let n = p.len() / stride;
                        Ok((p, vec![n]))
                    })
                    .collect::<Result<_, String>>()?,
            };
            for (p, vcount) in polygons {
                let mut k = 0;
                for &n in &vcount {
                    // A fan from the polygon's first corner (Collada's polygons are convex).
                    for j in 1..n.saturating_sub(1) {
                        out.1.push([corner(&p, k)?, corner(&p, k + j)?, corner(&p, k + j + 1)?]);
                    }
                    k += n;
                }
            }
        }
        Ok(())
    }

    /// The positions a VERTEX input leads to: `<vertices>` → its POSITION input → a `<source>`'s
    /// `<float_array>`, read with its accessor's stride.
    fn positions(&self, vertex: &Node) -> Result<Vec<Vec3>, String> {
        let resolve = |url: Option<&str>| {
            let id = url.and_then(|u| u.strip_prefix('#')).ok_or("a source that is not '#id'".to_string())?;
            self.ids.get(id).copied().ok_or_else(|| format!("'#{id}' is not in the file"))
        };
        let vertices = resolve(vertex.attribute("source"))?;
        let position = children(vertices, "input")
            .find(|i| i.attribute("semantic") == Some("POSITION"))
            .ok_or("<vertices> without a POSITION input")?;
        let source = resolve(position.attribute("source"))?;
        let array = child(source, "float_array").ok_or("a position <source> without a <float_array>")?;
        let values = floats(array)?;
        let stride = child(source, "technique_common")
            .and_then(|t| child(t, "accessor"))
            .and_then(|a| a.attribute("stride"))
            .map_or(Ok(3), |s| s.parse::<usize>().map_err(|e| format!("accessor stride '{s}': {e}")))?;
        if stride < 3 {
            return Err(format!("positions with a stride of {stride} (x, y, z need 3)"));
        }
        Ok(values.chunks_exact(stride).map(|c| Vec3::new(c[0], c[1], c[2])).collect())
    }
}

/// The visual scene `<scene><instance_visual_scene url>` names, else the first one.
fn visual_scene<'a>(root: Node<'a, 'a>, ids: &HashMap<&str, Node<'a, 'a>>) -> Option<Node<'a, 'a>> {
    let named = child(root, "scene")
        .and_then(|s| child(s, "instance_visual_scene"))
        .and_then(|i| i.attribute("url"))
        .and_then(|u| u.strip_prefix('#'))
        .and_then(|id| ids.get(id).copied());
    named.or_else(|| root.descendants().find(|n| is(*n, "visual_scene")))
}

fn is(node: Node, name: &str) -> bool {
    node.is_element() && node.tag_name().name() == name
}

fn child<'a>(node: Node<'a, 'a>, name: &str) -> Option<Node<'a, 'a>> {
    node.children().find(|n| is(*n, name))
}

fn children<'a, 'b>(node: Node<'a, 'a>, name: &'b str) -> impl Iterator<Item = Node<'a, 'a>> + use<'a, 'b> {
    node.children().filter(move |n| is(*n, name))
}

fn label(node: Node) -> String {
    node.attribute("id").or(node.attribute("name")).unwrap_or("(unnamed)").to_string()
}

fn floats(node: Node) -> Result<Vec<f32>, String> {
    node.text()
        .unwrap_or("")
        .split_ascii_whitespace()
        .map(|v| v.parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("'{v}' is not a finite number")))
        .collect()
}

fn indices(node: Option<Node>) -> Result<Vec<usize>, String> {
    let Some(node) = node else { return Ok(Vec::new()) };
    node.text()
        .unwrap_or("")
        .split_ascii_whitespace()
        .map(|v| v.parse::<usize>().map_err(|_| format!("'{v}' is not an index")))
        .collect()
}

fn vec3(values: &[f32], what: &str, node: Node) -> Result<Vec3, String> {
    match values {
        [x, y, z] => Ok(Vec3::new(*x, *y, *z)),
        _ => Err(format!("<{what}> of node '{}': not 3 numbers", label(node))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square as a polylist quad, in centimetres, Y up, placed by a node translated 1 m
    /// (100 cm) along its Y (up) axis and instanced twice through `instance_node`.
    const SQUARE: &str = r##"<?xml version="1.0"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit name="centimeter" meter="0.01"/><up_axis>Y_UP</up_axis></asset>
  <library_geometries><geometry id="sq" name="square"><mesh>
    <source id="sq-pos"><float_array id="sq-pos-array" count="12">0 0 0 100 0 0 100 0 100 0 0 100</float_array>
      <technique_common><accessor source="#sq-pos-array" count="4" stride="3"/></technique_common></source>
    <vertices id="sq-v"><input semantic="POSITION" source="#sq-pos"/></vertices>
    <polylist count="1"><input semantic="VERTEX" source="#sq-v" offset="0"/><input semantic="NORMAL" source="#n" offset="1"/>
      <vcount>4</vcount><p>0 0 1 0 2 0 3 0</p></polylist>
  </mesh></geometry></library_geometries>
  <library_nodes><node id="part"><instance_geometry url="#sq"/></node></library_nodes>
  <library_visual_scenes><visual_scene id="scene">
    <node name="up"><translate>0 100 0</translate><instance_node url="#part"/></node>
    <node name="again"><matrix>1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1</matrix><instance_node url="#part"/></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>"##;

    #[test]
    fn units_up_axis_nodes_and_polygons_are_applied() {
        let (vertices, triangles) = read(SQUARE, 5_000_000).unwrap();
        assert_eq!((vertices.len(), triangles.len()), (8, 4), "two instances of a quad fanned into two triangles");
        // Y up turned to Z up, centimetres to metres: the translated copy's corners at z = 1 m.
        let lifted: Vec<Vec3> = vertices[..4].to_vec();
        assert!(lifted.iter().all(|v| (v.z - 1.0).abs() < 1e-6), "{lifted:?}");
        assert!((lifted[1] - Vec3::new(1.0, 0.0, 1.0)).length() < 1e-6, "{lifted:?}");
        // The file's +Z (depth) becomes the link's −Y.
        assert!((lifted[3] - Vec3::new(0.0, -1.0, 1.0)).length() < 1e-6, "{lifted:?}");
    }

    #[test]
    fn broken_references_and_numbers_are_named() {
        let bad_index = SQUARE.replace("<p>0 0 1 0 2 0 3 0</p>", "<p>0 0 1 0 2 0 9 0</p>");
        assert!(read(&bad_index, 5_000_000).unwrap_err().contains("names position 9 of 4"));
        let bad_number = SQUARE.replace("100 0 100 0", "100 0 nan 0");
        assert!(read(&bad_number, 5_000_000).unwrap_err().contains("'nan' is not a finite number"));
        let missing = SQUARE.replace("url=\"#part\"", "url=\"#gone\"");
        assert!(read(&missing, 5_000_000).unwrap_err().contains("'#gone'"));
        let looping = SQUARE.replace("<instance_geometry url=\"#sq\"/>", "<instance_node url=\"#part\"/>");
        assert!(read(&looping, 5_000_000).unwrap_err().contains("nested deeper"));
        assert!(read("<robot/>", 5_000_000).unwrap_err().contains("not a Collada document"));
        // Instances are counted as they are placed: the second of the square's two is refused
        // under a cap of 1 (nodes that each instance another twice would ask for 2^64 copies).
        assert!(read(SQUARE, 1).unwrap_err().contains("more than 1 triangles once its instances are placed"));
    }
}
