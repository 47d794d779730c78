//! Mesh files as CAD tools export them: STL (binary or ASCII), Wavefront OBJ, glTF 2.0
//! (`.glb`, or `.gltf` with its buffers beside it or inline) and Collada (`.dae`, see
//! [`super::collada`]), read into one triangle list in the file's own units and axes (no Y-up
//! conversion: a URDF's mesh is in its link's frame; Collada's own `<unit>` and `<up_axis>`
//! excepted, which the file declares). A file over [`MAX_BYTES`] or [`MAX_TRIANGLES`] is refused.
//! Where a URDF's `package://` and relative mesh paths lead is [`resolve`].

use std::path::{Path, PathBuf};

use bevy::math::{Mat4, Vec3};

/// The mesh formats read, by file extension.
pub const FORMATS: &str = "STL (.stl), OBJ (.obj), glTF (.glb, .gltf), Collada (.dae)";

/// The largest mesh file read (bytes): a robot's link meshes are kilobytes to a few megabytes.
pub const MAX_BYTES: u64 = 256 << 20;

/// The most triangles one mesh file may hold.
pub const MAX_TRIANGLES: usize = 5_000_000;

/// A mesh file's triangles: vertices and index triples.
pub type Triangles = (Vec<Vec3>, Vec<[u32; 3]>);

/// The triangles of Collada text (as [`read`] reads a `.dae` file; for checking the reader).
pub fn parse_collada(text: &str) -> Result<Triangles, String> {
    super::collada::read(text, MAX_TRIANGLES)
}

/// Reads the triangles of the mesh file at `path`, by its extension.
pub fn read(path: &Path) -> Result<Triangles, String> {
    let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    let bytes = read_bounded(path)?;
    let (vertices, triangles) = match extension.as_str() {
        "stl" => stl(&bytes),
        "obj" => obj(&bytes),
        "glb" | "gltf" => gltf(&bytes, path),
        "dae" => std::str::from_utf8(&bytes)
            .map_err(|e| format!("not UTF-8 text: {e}"))
            .and_then(|text| super::collada::read(text, MAX_TRIANGLES))
            .map_err(|e| format!("{}: {e}", path.display())),
        _ => Err(format!("{}: not a mesh format twinbots reads ({FORMATS})", path.display())),
    }?;
    if triangles.is_empty() {
        return Err(format!("{} holds no triangles", path.display()));
    }
    if triangles.len() > MAX_TRIANGLES {
        return Err(format!(
            "{}: {} triangles, more than the {MAX_TRIANGLES} a mesh may have",
            path.display(),
            triangles.len()
        ));
    }
    if let Some(t) = triangles.iter().find(|t| t.iter().any(|&i| i as usize >= vertices.len())) {
        return Err(format!("{}: triangle {t:?} names a vertex beyond its {}", path.display(), vertices.len()));
    }
    Ok((vertices, triangles))
}

/// The file's bytes, refused past [`MAX_BYTES`] (read no further, so a device that never ends
/// cannot exhaust the memory).
fn read_bounded(path: &Path) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| format!("not found at {}: {e}", path.display()))?;
    // A device or a pipe is not a mesh (`/dev/zero` never ends, a FIFO may never answer).
    let kind = file.metadata().map_err(|e| format!("{}: {e}", path.display()))?;
    if !kind.is_file() {
        return Err(format!("{}: not a regular file", path.display()));
    }
    let mut bytes = Vec::new();
    file.take(MAX_BYTES + 1).read_to_end(&mut bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    if bytes.len() as u64 > MAX_BYTES {
        return Err(format!("{}: larger than the {} MB a mesh file may be", path.display(), MAX_BYTES >> 20));
    }
    Ok(bytes)
}

fn stl(bytes: &[u8]) -> Result<Triangles, String> {
    let stl = stl_io::read_stl(&mut std::io::Cursor::new(bytes)).map_err(|e| format!("not a valid STL: {e}"))?;
    let vertices = stl.vertices.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect();
    Ok((vertices, stl.faces.iter().map(|f| f.vertices.map(|i| i as u32)).collect()))
}

fn obj(bytes: &[u8]) -> Result<Triangles, String> {
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ignore_points: true, ignore_lines: true };
    // Materials (.mtl) colour visuals in other viewers; the geometry is all a twin takes, so
    // they are not opened.
    let no_materials = |_: &Path| Err(tobj::LoadError::OpenFileFailed);
    let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &options, no_materials)
        .map_err(|e| format!("not a valid OBJ: {e}"))?;
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    for model in models {
        let base = vertices.len();
        vertices.extend(model.mesh.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        for t in model.mesh.indices.chunks_exact(3) {
            triangles.push(
                offset_triangle(base, vertices.len() - base, t).map_err(|e| format!("object '{}': {e}", model.name))?,
            );
        }
    }
    Ok((vertices, triangles))
}

fn gltf(bytes: &[u8], path: &Path) -> Result<Triangles, String> {
    let file = gltf::Gltf::from_slice(bytes).map_err(|e| format!("not a valid glTF: {e}"))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let buffers: Vec<Vec<u8>> = file
        .buffers()
        .map(|b| match b.source() {
            gltf::buffer::Source::Bin => file
                .blob
                .clone()
                .ok_or_else(|| format!("buffer {} is the binary chunk, which the file lacks", b.index())),
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                data_uri(uri).map_err(|e| format!("buffer {}: {e}", b.index()))
            }
            gltf::buffer::Source::Uri(uri) => {
                // A buffer lies beside its glTF file: no scheme, no absolute path, no way up.
                let relative = Path::new(uri);
                if uri.contains("://")
                    || relative.is_absolute()
                    || relative.components().any(|c| c == std::path::Component::ParentDir)
                {
                    return Err(format!("buffer {}: '{uri}' is not a path beside the glTF file", b.index()));
                }
                read_bounded(&dir.join(relative)).map_err(|e| format!("buffer {}: {e}", b.index()))
            }
        })
        .collect::<Result<_, _>>()?;
    let mut out = (Vec::new(), Vec::new());
    // The default scene's nodes with their transforms; a file without scenes: every mesh as is.
    match file.default_scene().or_else(|| file.scenes().next()) {
        Some(scene) => {
            for node in scene.nodes() {
                gltf_node(&node, Mat4::IDENTITY, &buffers, &mut out)?;
            }
        }
        None => {
            for mesh in file.meshes() {
                gltf_mesh(&mesh, Mat4::IDENTITY, &buffers, &mut out)?;
            }
        }
    }
    Ok(out)
}

fn gltf_node(node: &gltf::Node, parent: Mat4, buffers: &[Vec<u8>], out: &mut Triangles) -> Result<(), String> {
    let pose = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
    if let Some(mesh) = node.mesh() {
        gltf_mesh(&mesh, pose, buffers, out)?;
    }
    for child in node.children() {
        gltf_node(&child, pose, buffers, out)?;
    }
    Ok(())
}

fn gltf_mesh(mesh: &gltf::Mesh, pose: Mat4, buffers: &[Vec<u8>], out: &mut Triangles) -> Result<(), String> {
    for primitive in mesh.primitives() {
        // Points and lines have no surface to collide with or see.
        if primitive.mode() != gltf::mesh::Mode::Triangles {
            continue;
        }
        let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
        let positions = reader
            .read_positions()
            .ok_or_else(|| format!("mesh {} has a primitive without positions", mesh.index()))?;
        let base = out.0.len();
        out.0.extend(positions.map(|p| pose.transform_point3(Vec3::from_array(p))));
        let count = out.0.len() - base;
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..count as u32).collect(),
        };
        for t in indices.chunks_exact(3) {
            out.1.push(offset_triangle(base, count, t).map_err(|e| format!("mesh {}: {e}", mesh.index()))?);
        }
    }
    Ok(())
}

/// A part's triangle `t` (indices into its `count` vertices) in the whole mesh's numbering, its
/// vertices starting at `base`: an index beyond the part is an error, never an index that
/// wraps round into another part's vertices.
fn offset_triangle(base: usize, count: usize, t: &[u32]) -> Result<[u32; 3], String> {
    let mut out = [0u32; 3];
    for (o, &i) in out.iter_mut().zip(t) {
        if i as usize >= count {
            return Err(format!("a triangle names vertex {i} of {count}"));
        }
        *o = u32::try_from(base + i as usize).map_err(|_| "more vertices than 32-bit indices reach".to_string())?;
    }
    Ok(out)
}

/// A `data:...;base64,` URI's bytes.
fn data_uri(uri: &str) -> Result<Vec<u8>, String> {
    use base64::Engine;
    let (_, payload) = uri.split_once(";base64,").ok_or("a data URI that is not base64")?;
    base64::engine::general_purpose::STANDARD.decode(payload).map_err(|e| format!("bad base64 in a data URI: {e}"))
}

/// Where a URDF's mesh `filename` is, or every place it was looked for. `package://PKG/REST`
/// is found, in this order, as `DIR/PKG/REST` for each `DIR` of `package_path`
/// (`TWINBOTS_PACKAGE_PATH`, then `ROS_PACKAGE_PATH`), as `ANCESTOR/REST` for the URDF's folder
/// or any folder above it named `PKG` (a URDF inside its own package), and as `URDF_DIR/REST`;
/// `file://PATH` is PATH; a plain path is relative to the URDF's folder. Other URI schemes are
/// errors.
pub fn resolve(filename: &str, urdf_dir: &Path, package_path: &[PathBuf]) -> Result<PathBuf, String> {
    if let Some(rest) = filename.strip_prefix("file://") {
        return Ok(PathBuf::from(rest));
    }
    let Some(rest) = filename.strip_prefix("package://") else {
        if let Some((scheme, _)) = filename.split_once("://") {
            return Err(format!(
                "mesh '{filename}': unknown URI scheme '{scheme}://' (package:// and file:// are read)"
            ));
        }
        return Ok(urdf_dir.join(filename));
    };
    let (package, inner) =
        rest.split_once('/').ok_or_else(|| format!("mesh '{filename}': package:// needs a package and a path"))?;
    // A package path stays inside its package.
    let inner_path = Path::new(inner);
    if inner_path.is_absolute() || inner_path.components().any(|c| c == std::path::Component::ParentDir) {
        return Err(format!(
            "mesh '{filename}': a package:// path may not leave its package ('..' or an absolute path)"
        ));
    }
    let mut tried = Vec::new();
    let candidates = package_path
        .iter()
        .map(|dir| dir.join(package).join(inner))
        .chain(urdf_dir.ancestors().filter(|a| a.file_name().is_some_and(|n| n == package)).map(|a| a.join(inner)))
        .chain(std::iter::once(urdf_dir.join(inner)));
    for candidate in candidates {
        if candidate.is_file() {
            return Ok(candidate);
        }
        tried.push(candidate.display().to_string());
    }
    Err(format!(
        "mesh '{filename}' not found; looked at {} (TWINBOTS_PACKAGE_PATH and ROS_PACKAGE_PATH add places)",
        tried.join(", ")
    ))
}

/// Packages a robot file names (`[packages]`: a package's name and its folder).
pub type NamedPackages = [(String, PathBuf)];

/// [`resolve`], with `package://NAME/REST` found first as `FOLDER/REST` for a package of
/// `named` (a robot file's `[packages]`); a path there that is not a file is an error naming it.
pub fn resolve_in(
    filename: &str,
    urdf_dir: &Path,
    named: &NamedPackages,
    package_path: &[PathBuf],
) -> Result<PathBuf, String> {
    if let Some((package, inner)) = filename.strip_prefix("package://").and_then(|rest| rest.split_once('/'))
        && let Some((_, folder)) = named.iter().find(|(name, _)| name == package)
    {
        let inner_path = Path::new(inner);
        if inner_path.is_absolute() || inner_path.components().any(|c| c == std::path::Component::ParentDir) {
            return Err(format!(
                "mesh '{filename}': a package:// path may not leave its package ('..' or an absolute path)"
            ));
        }
        let candidate = folder.join(inner);
        return if candidate.is_file() {
            Ok(candidate)
        } else {
            Err(format!("'{filename}' not found: no file {} (package '{package}' of [packages])", candidate.display()))
        };
    }
    resolve(filename, urdf_dir, package_path)
}

/// The package search path from the environment: `TWINBOTS_PACKAGE_PATH`, then
/// `ROS_PACKAGE_PATH`, each a `:`-separated list of folders.
pub fn package_path_from_env() -> Vec<PathBuf> {
    ["TWINBOTS_PACKAGE_PATH", "ROS_PACKAGE_PATH"]
        .iter()
        .filter_map(std::env::var_os)
        .flat_map(|v| std::env::split_paths(&v).collect::<Vec<_>>())
        .filter(|p| !p.as_os_str().is_empty())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("twinbots-mesh-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn package_uris_resolve_through_the_path_then_the_urdfs_own_package() {
        let root = scratch("resolve");
        let share = root.join("share");
        std::fs::create_dir_all(share.join("arm_description/meshes")).unwrap();
        std::fs::write(share.join("arm_description/meshes/a.stl"), "x").unwrap();
        let own = root.join("src/cell_description/urdf");
        std::fs::create_dir_all(&own).unwrap();
        std::fs::create_dir_all(root.join("src/cell_description/meshes")).unwrap();
        std::fs::write(root.join("src/cell_description/meshes/b.obj"), "x").unwrap();
        let path = [share.clone()];
        assert_eq!(
            resolve("package://arm_description/meshes/a.stl", &own, &path).unwrap(),
            share.join("arm_description/meshes/a.stl")
        );
        assert_eq!(
            resolve("package://cell_description/meshes/b.obj", &own, &[]).unwrap(),
            root.join("src/cell_description/meshes/b.obj")
        );
        let e = resolve("package://arm_description/meshes/a.stl", &own, &[]).unwrap_err();
        assert!(e.contains("not found; looked at") && e.contains("TWINBOTS_PACKAGE_PATH"), "{e}");
        let e = resolve("package://arm_description/../../../etc/passwd", &own, &path).unwrap_err();
        assert!(e.contains("may not leave its package"), "{e}");
        let e = read(Path::new("/dev/zero.stl")).unwrap_err();
        assert!(e.contains("not found"), "{e}");
        let e = read_bounded(Path::new("/dev/zero")).unwrap_err();
        assert!(e.contains("not a regular file"), "{e}");
        let e = resolve("http://example.com/a.stl", &own, &path).unwrap_err();
        assert!(e.contains("unknown URI scheme 'http://'"), "{e}");
        assert_eq!(resolve("meshes/c.stl", &own, &path).unwrap(), own.join("meshes/c.stl"));
    }

    #[test]
    fn obj_and_gltf_read_the_same_triangles() {
        let dir = scratch("formats");
        let obj = dir.join("t.obj");
        std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n").unwrap();
        let (v, t) = read(&obj).unwrap();
        assert_eq!((v.len(), t.len()), (4, 4));
        let empty = dir.join("e.obj");
        std::fs::write(&empty, "# nothing\n").unwrap();
        assert!(read(&empty).unwrap_err().contains("no triangles"));
        let other = dir.join("m.3ds");
        std::fs::write(&other, "3ds").unwrap();
        assert!(read(&other).unwrap_err().contains("not a mesh format twinbots reads"));
        let collada = dir.join("m.dae");
        std::fs::write(&collada, "<COLLADA/>").unwrap();
        assert!(read(&collada).unwrap_err().contains("holds no triangles"));
        // A tetrahedron in a .gltf with an inline buffer, its node lifted 2 m.
        use base64::Engine;
        let mut bin: Vec<u8> = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        bin.extend([0u16, 1, 2, 0, 1, 3, 0, 2, 3, 1, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
        let data = base64::engine::general_purpose::STANDARD.encode(&bin);
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"translation":[0,0,2]}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
            "buffers":[{{"byteLength":72,"uri":"data:application/octet-stream;base64,{data}"}}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}},
                         {{"bufferView":1,"componentType":5123,"count":12,"type":"SCALAR"}}]}}"#
        );
        let gltf = dir.join("t.gltf");
        std::fs::write(&gltf, json).unwrap();
        let (gv, gt) = read(&gltf).unwrap();
        assert_eq!(gt, t, "the same faces");
        assert_eq!(gv.iter().map(|p| *p - Vec3::Z * 2.0).collect::<Vec<_>>(), v, "the node's translation applied");
        let bad = dir.join("b.glb");
        std::fs::write(&bad, "glTF not really").unwrap();
        assert!(read(&bad).unwrap_err().contains("not a valid glTF"));
        // A buffer outside the glTF's folder, and an index past the part's vertices (it wrapped
        // round a u32 into garbage triangles before).
        std::fs::write(dir.join("buffer.bin"), &bin).unwrap();
        for (uri, expected) in [("../buffer.bin", "not a path beside"), ("/etc/passwd", "not a path beside")] {
            let escaping = dir.join("escaping.gltf");
            std::fs::write(&escaping, json_of(&format!("{{\"byteLength\":72,\"uri\":\"{uri}\"}}"))).unwrap();
            let e = read(&escaping).unwrap_err();
            assert!(e.contains(expected), "{uri}: {e}");
        }
        let mut wrapping = bin.clone();
        wrapping[48..50].copy_from_slice(&9u16.to_le_bytes());
        let wild = dir.join("wild.gltf");
        let data = base64::engine::general_purpose::STANDARD.encode(&wrapping);
        std::fs::write(
            &wild,
            json_of(&format!("{{\"byteLength\":72,\"uri\":\"data:application/octet-stream;base64,{data}\"}}")),
        )
        .unwrap();
        let e = read(&wild).unwrap_err();
        assert!(e.contains("names vertex 9 of 4"), "{e}");
    }

    /// The tetrahedron's glTF with `buffer` as its one buffer.
    fn json_of(buffer: &str) -> String {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
            "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
            "buffers":[{buffer}],
            "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}},
                         {{"bufferView":1,"componentType":5123,"count":12,"type":"SCALAR"}}]}}"#
        )
    }
}
