//! Mesh readers and mesh inspection, end to end.
//!
//! In: small synthetic files written to a temporary directory (every format, layout and
//! encoding, plus hostile input) and the real shape models under `data/shapes`. Out:
//! exact vertex/triangle comparisons, errors that name the file and the line, and the
//! known topology of the real shapes.

use glam::DVec3;
use slim::mesh::inspect::{inspect, MeshReport};
use slim::mesh::{read_mesh, LengthUnit, Mesh, MeshFormat, RawMesh};
use std::path::{Path, PathBuf};

#[path = "common/temp_dir.rs"]
mod temp_dir;
use temp_dir::TempDir;

// ---------------------------------------------------------------------------------------
// Helpers

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write temp file");
    path
}

fn read(path: &Path) -> RawMesh {
    read_mesh(path, None).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

/// Reading `bytes` as `name` must fail, naming the file and containing every `needle`.
fn expect_error(dir: &Path, name: &str, bytes: impl AsRef<[u8]>, needles: &[&str]) -> String {
    let path = write(dir, name, bytes);
    let message = match read_mesh(&path, None) {
        Ok(mesh) => panic!("{name}: expected an error, read {mesh:?}"),
        Err(e) => e.to_string(),
    };
    assert!(
        message.contains(name),
        "{name}: error does not name the file: {message}"
    );
    for needle in needles {
        assert!(
            message.contains(needle),
            "{name}: '{needle}' not in: {message}"
        );
    }
    message
}

fn shape(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data/shapes")
        .join(relative)
}

/// A unit tetrahedron with outward-facing triangles.
fn tetrahedron() -> RawMesh {
    RawMesh {
        vertices: vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z],
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    }
}

/// A unit cube with outward-facing triangles.
fn cube() -> RawMesh {
    let vertices = (0..8)
        .map(|i| DVec3::new(f64::from(i & 1), f64::from((i >> 1) & 1), f64::from(i >> 2)))
        .collect();
    // Quads counter-clockwise seen from outside, split along a diagonal.
    let quads = [
        [0, 2, 3, 1], // z = 0
        [4, 5, 7, 6], // z = 1
        [0, 1, 5, 4], // y = 0
        [2, 6, 7, 3], // y = 1
        [0, 4, 6, 2], // x = 0
        [1, 3, 7, 5], // x = 1
    ];
    let triangles = quads
        .iter()
        .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
        .collect();
    RawMesh {
        vertices,
        triangles,
    }
}

fn octahedron() -> RawMesh {
    let vertices = vec![
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
    ];
    // Wound so that every normal points away from the origin.
    let triangles = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    RawMesh {
        vertices,
        triangles,
    }
}

fn report(raw: RawMesh) -> MeshReport {
    inspect(&Mesh::from_raw(raw, LengthUnit::M))
}

fn obj_text(mesh: &RawMesh) -> String {
    let mut text = String::new();
    for v in &mesh.vertices {
        text += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in &mesh.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    text
}

// ---------------------------------------------------------------------------------------
// OBJ

#[test]
fn obj_reads_face_forms_negative_indices_quads_and_crlf() {
    let dir = TempDir::new("mesh-readers", "obj");
    let text = "# a tetrahedron and a quad\r\n\
                mtllib shape.mtl\r\n\
                o body\r\n\
                v 0 0 0 1.0\r\n\
                v 1 0 0 0.5 0.5 0.5\r\n\
                v 0 1 0\r\n\
                v 0 0 1   \r\n\
                vt 0 0\r\nvt 1 0\r\nvt 0 1\r\n\
                vn 0 0 1\r\n\
                usemtl rock\r\n\
                g part\r\ns 1\r\n\
                f 1/1 3/2 2/3\r\n\
                f 1//1 2//1 4//1\r\n\
                f 1/1/1 4/2/1 3/3/1\r\n\
                f -3 -2 -1\r\n\
                l 1 2\r\n\
                v 1 1 0\r\n\
                f 1 2 5 3 # quad, fanned\r\n";
    let mesh = read(&write(&dir, "shape.obj", text));
    let mut expected = tetrahedron();
    expected.vertices.push(DVec3::new(1.0, 1.0, 0.0));
    expected.triangles.extend([[0, 1, 4], [0, 4, 2]]);
    assert_eq!(mesh, expected);
}

#[test]
fn obj_rejects_index_zero_short_faces_and_bad_numbers() {
    let dir = TempDir::new("mesh-readers", "obj-errors");
    let tetra = obj_text(&tetrahedron());
    expect_error(
        &dir,
        "zero.obj",
        format!("{tetra}f 0 1 2\n"),
        &["line 9", "index 0"],
    );
    expect_error(
        &dir,
        "short.obj",
        format!("{tetra}f 1 2\n"),
        &["line 9", "2 vertices"],
    );
    expect_error(&dir, "word.obj", "v 0 0 zero\n", &["line 1", "'zero'"]);
    expect_error(&dir, "few.obj", "v 0 0\n", &["line 1", "3 (x y z)"]);
    expect_error(&dir, "slash.obj", format!("{tetra}f /1 2 3\n"), &["line 9"]);
    expect_error(&dir, "rel.obj", "v 0 0 0\nf -1 -2 -3\n", &["line 2", "-2"]);
    expect_error(
        &dir,
        "big.obj",
        format!("{tetra}f 1 2 99999999999\n"),
        &["line 9", "32 bits"],
    );
}

// ---------------------------------------------------------------------------------------
// PLY

/// A tetrahedron as PLY with extra vertex properties (normals, colour) and an extra
/// element with a list before and after the faces.
fn ply_tetrahedron(format: &str) -> Vec<u8> {
    let mesh = tetrahedron();
    let mut bytes = format!(
        "ply\r\nformat {format} 1.0\r\ncomment made by a test\r\nobj_info none\r\n\
         element vertex 4\r\nproperty float x\r\nproperty double y\r\nproperty short z\r\n\
         property float nx\r\nproperty float ny\r\nproperty float nz\r\nproperty uchar red\r\n\
         element material 2\r\nproperty list uchar int ids\r\nproperty double shine\r\n\
         element face 4\r\nproperty uchar flags\r\nproperty list uchar uint vertex_indices\r\n\
         element edge 1\r\nproperty list ushort int vertex1\r\nproperty char crease\r\n\
         end_header\r\n"
    )
    .into_bytes();
    let mut body = PlyBody::new(format, &mut bytes);
    for v in &mesh.vertices {
        body.f32(v.x as f32);
        body.f64(v.y);
        body.i16(v.z as i16);
        body.f32(0.5);
        body.f32(-0.5);
        body.f32(1.0);
        body.u8(200);
        body.end_row();
    }
    for material in 0..2 {
        body.u8(material);
        for id in 0..material {
            body.i32(i32::from(id) - 7);
        }
        body.f64(0.25);
        body.end_row();
    }
    for t in &mesh.triangles {
        body.u8(1);
        body.u8(3);
        for &i in t {
            body.u32(i);
        }
        body.end_row();
    }
    body.u16(2);
    body.i32(1);
    body.i32(-2);
    body.i8(-1);
    body.end_row();
    bytes
}

/// Writes PLY body values in one of the three encodings.
struct PlyBody<'a> {
    out: &'a mut Vec<u8>,
    ascii: bool,
    big_endian: bool,
}

impl<'a> PlyBody<'a> {
    fn new(format: &str, out: &'a mut Vec<u8>) -> Self {
        PlyBody {
            out,
            ascii: format == "ascii",
            big_endian: format == "binary_big_endian",
        }
    }

    fn value(&mut self, text: String, le: &[u8], be: &[u8]) {
        if self.ascii {
            self.out.extend_from_slice(text.as_bytes());
            self.out.push(b' ');
        } else if self.big_endian {
            self.out.extend_from_slice(be);
        } else {
            self.out.extend_from_slice(le);
        }
    }

    fn end_row(&mut self) {
        if self.ascii {
            self.out.push(b'\n');
        }
    }

    fn u8(&mut self, v: u8) {
        self.value(v.to_string(), &[v], &[v]);
    }
    fn i8(&mut self, v: i8) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn u16(&mut self, v: u16) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn i16(&mut self, v: i16) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.value(v.to_string(), &v.to_le_bytes(), &v.to_be_bytes());
    }
}

const PLY_FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

#[test]
fn ply_reads_all_encodings_skipping_extra_properties_and_elements() {
    let dir = TempDir::new("mesh-readers", "ply");
    for format in PLY_FORMATS {
        let mesh = read(&write(
            &dir,
            &format!("{format}.ply"),
            ply_tetrahedron(format),
        ));
        assert_eq!(mesh, tetrahedron(), "{format}");
    }
}

#[test]
fn ply_fan_triangulates_polygons() {
    let dir = TempDir::new("mesh-readers", "ply-quad");
    let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty int x\nproperty int y\n\
                property int z\nelement face 1\nproperty list uchar int vertex_index\n\
                end_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
    let mesh = read(&write(&dir, "quad.ply", text));
    assert_eq!(mesh.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(mesh.vertices[2], DVec3::new(1.0, 1.0, 0.0));
}

#[test]
fn ply_errors_name_line_or_byte() {
    let dir = TempDir::new("mesh-readers", "ply-errors");
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                  property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                  end_header\n";
    expect_error(
        &dir,
        "nan.ply",
        format!("{header}0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"),
        &["line 11", "finite"],
    );
    expect_error(
        &dir,
        "range.ply",
        format!("{header}0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
        &["line 13", "face index 3 out of range (file has 3 vertices)"],
    );
    expect_error(
        &dir,
        "neg.ply",
        format!("{header}0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
        &["line 13", "-1"],
    );
    expect_error(
        &dir,
        "short.ply",
        format!("{header}0 0 0\n1 0 0\n"),
        &["file ends after 2 of 3 'vertex' elements"],
    );
    expect_error(
        &dir,
        "extra.ply",
        format!("{header}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n7\n"),
        &["line 14", "after the last element"],
    );
    expect_error(
        &dir,
        "word.ply",
        format!("{header}0 0 0\n1 x 0\n"),
        &["line 11", "'x'"],
    );
    expect_error(
        &dir,
        "type.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty real x\n",
        &["line 4", "'real'"],
    );
    expect_error(
        &dir,
        "noend.ply",
        "ply\nformat ascii 1.0\nelement vertex 3\n",
        &["end_header"],
    );
    expect_error(&dir, "noface.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n", &["'face'"]);
    expect_error(
        &dir,
        "version.ply",
        "ply\nformat ascii 2.0\n",
        &["line 2", "'2.0'"],
    );
    // Binary: a NaN coordinate is reported at its byte offset.
    let binary = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n\
                  property float y\nproperty float z\nelement face 0\n\
                  property list uchar int vertex_indices\nend_header\n";
    let mut bytes = binary.as_bytes().to_vec();
    for v in [0.0f32, f32::NAN, 0.0] {
        bytes.extend(v.to_le_bytes());
    }
    let offset = binary.len() + 4;
    expect_error(
        &dir,
        "nan-binary.ply",
        bytes,
        &[&format!("byte {offset}"), "finite"],
    );
}

// ---------------------------------------------------------------------------------------
// STL

fn stl_ascii(mesh: &RawMesh) -> String {
    let mut text = String::from("solid tetra\n");
    for t in &mesh.triangles {
        text += "  facet normal 0 0 0\n    outer loop\n";
        for &i in t {
            let v = mesh.vertices[i as usize];
            text += &format!("      vertex {:e} {:e} {:e}\n", v.x, v.y, v.z);
        }
        text += "    endloop\n  endfacet\n";
    }
    text + "endsolid tetra\n"
}

fn stl_binary(mesh: &RawMesh, header: &[u8]) -> Vec<u8> {
    let mut bytes = vec![b' '; 80];
    bytes[..header.len()].copy_from_slice(header);
    bytes.extend((mesh.triangles.len() as u32).to_le_bytes());
    for t in &mesh.triangles {
        bytes.extend([0u8; 12]); // the normal, ignored
        for &i in t {
            for c in mesh.vertices[i as usize].to_array() {
                bytes.extend((c as f32).to_le_bytes());
            }
        }
        bytes.extend([0u8; 2]);
    }
    bytes
}

/// The corner positions of each triangle: STL numbers merged vertices in the order
/// it first meets them, so meshes are compared by position.
fn facet_corners(mesh: &RawMesh) -> Vec<[DVec3; 3]> {
    mesh.triangles
        .iter()
        .map(|t| t.map(|i| mesh.vertices[i as usize]))
        .collect()
}

fn assert_same_welded_tetrahedron(mesh: &RawMesh, name: &str) {
    assert_eq!(mesh.vertices.len(), 4, "{name}: equal corners are merged");
    assert_eq!(facet_corners(mesh), facet_corners(&tetrahedron()), "{name}");
}

#[test]
fn stl_reads_ascii_and_merges_equal_corners() {
    let dir = TempDir::new("mesh-readers", "stl-ascii");
    let mesh = read(&write(&dir, "tetra.stl", stl_ascii(&tetrahedron())));
    assert_same_welded_tetrahedron(&mesh, "tetra.stl");
    assert_eq!(
        mesh.triangles,
        vec![[0, 1, 2], [0, 2, 3], [0, 3, 1], [2, 1, 3]]
    );
    // Upper-case keywords and CRLF are accepted too.
    let shouty = stl_ascii(&tetrahedron())
        .to_uppercase()
        .replace('\n', "\r\n");
    assert_same_welded_tetrahedron(&read(&write(&dir, "shouty.stl", shouty)), "shouty.stl");
}

#[test]
fn stl_merges_negative_and_positive_zero() {
    let dir = TempDir::new("mesh-readers", "stl-zero");
    let text = stl_ascii(&tetrahedron()).replacen("vertex 0e0 0e0 0e0", "vertex -0e0 0e0 -0e0", 1);
    assert_same_welded_tetrahedron(&read(&write(&dir, "zero.stl", text)), "zero.stl");
}

#[test]
fn stl_reads_binary_even_when_the_header_starts_with_solid() {
    let dir = TempDir::new("mesh-readers", "stl-binary");
    for (name, header) in [
        ("plain.stl", &b"binary tetra"[..]),
        ("solid.stl", b"solid tetra exported by a CAD tool"),
    ] {
        let mesh = read(&write(&dir, name, stl_binary(&tetrahedron(), header)));
        assert_same_welded_tetrahedron(&mesh, name);
    }
}

#[test]
fn stl_errors() {
    let dir = TempDir::new("mesh-readers", "stl-errors");
    let text = stl_ascii(&tetrahedron());
    expect_error(
        &dir,
        "nan.stl",
        text.replacen("vertex 0e0", "vertex NaN", 1),
        &["line 4", "finite"],
    );
    expect_error(
        &dir,
        "cut.stl",
        &text[..text.len() / 2],
        &["file ends", "complete facets"],
    );
    expect_error(
        &dir,
        "quad.stl",
        text.replacen("    endloop", "      vertex 1 1 1\n    endloop", 1),
        &["line 8", "4 vertices"],
    );
    let binary = stl_binary(&tetrahedron(), b"x");
    expect_error(
        &dir,
        "cut-binary.stl",
        &binary[..84 + 50 * 2 + 7],
        &["byte 184", "file ends after 2 of 4 facets"],
    );
    let mut nan = binary.clone();
    nan[84 + 50 + 12 + 4..84 + 50 + 16 + 4].copy_from_slice(&f32::INFINITY.to_le_bytes());
    expect_error(&dir, "inf-binary.stl", nan, &["byte 150", "finite"]);
    expect_error(&dir, "tiny.stl", b"\x01\x02\x03", &["too short"]);
}

// ---------------------------------------------------------------------------------------
// PDS plate files

#[test]
fn pds_reads_tagged_layout_zero_and_one_based() {
    let dir = TempDir::new("mesh-readers", "pds-tagged");
    let one_based = obj_text(&tetrahedron());
    assert_eq!(read(&write(&dir, "one.tab", &one_based)), tetrahedron());
    let mut zero_based = String::from("# zero-based plates\r\n");
    for v in &tetrahedron().vertices {
        zero_based += &format!("V {} {} {}\r\n", v.x, v.y, v.z);
    }
    for t in &tetrahedron().triangles {
        zero_based += &format!("F {} {} {}\r\n", t[0], t[1], t[2]);
    }
    assert_eq!(read(&write(&dir, "zero.txt", zero_based)), tetrahedron());
}

/// Vertex and plate rows of the tetrahedron, with an optional id column and index base.
fn pds_rows(ids: bool, base: u32) -> (String, String) {
    let mesh = tetrahedron();
    let id = |i: usize| {
        if ids {
            format!("{} ", i + 1)
        } else {
            String::new()
        }
    };
    let vertices = mesh
        .vertices
        .iter()
        .enumerate()
        .map(|(i, v)| format!("{}{:.5E} {:.5E} {:.5E}\n", id(i), v.x, v.y, v.z))
        .collect();
    let plates = mesh
        .triangles
        .iter()
        .enumerate()
        .map(|(i, t)| format!("{}{} {} {}\n", id(i), t[0] + base, t[1] + base, t[2] + base))
        .collect();
    (vertices, plates)
}

#[test]
fn pds_reads_counted_layout_with_and_without_ids() {
    let dir = TempDir::new("mesh-readers", "pds-counted");
    for ids in [false, true] {
        for base in [0, 1] {
            let (vertices, plates) = pds_rows(ids, base);
            let name = format!("counted-{ids}-{base}.txt");
            let mesh = read(&write(&dir, &name, format!("4 4\n{vertices}{plates}")));
            assert_eq!(mesh, tetrahedron(), "{name}");
        }
    }
}

#[test]
fn pds_reads_classic_layout() {
    let dir = TempDir::new("mesh-readers", "pds-classic");
    for base in [0, 1] {
        let (vertices, plates) = pds_rows(true, base);
        let name = format!("classic-{base}.tab");
        let text = format!("4\r\n{vertices}4\r\n{plates}").replace('\n', "\r\n");
        assert_eq!(read(&write(&dir, &name, text)), tetrahedron(), "{name}");
    }
}

#[test]
fn pds_errors() {
    let dir = TempDir::new("mesh-readers", "pds-errors");
    let (vertices, plates) = pds_rows(false, 1);
    let counted = format!("4 4\n{vertices}{plates}");
    expect_error(
        &dir,
        "columns.txt",
        counted.replacen("1 2 3\n", "1 2 3 4 5\n", 1).replacen(
            "0.00000E0 0.00000E0 0.00000E0",
            "0 0",
            1,
        ),
        &["line 2", "found 2"],
    );
    expect_error(
        &dir,
        "nan.txt",
        counted.replacen("0.00000E0 0.00000E0 0.00000E0", "0 nan 0", 1),
        &["line 2", "'nan'"],
    );
    expect_error(
        &dir,
        "range.txt",
        counted.replacen("2 3 4", "2 3 9", 1),
        &["line 9", "face index 9 out of range (file has 4 vertices)"],
    );
    expect_error(
        &dir,
        "early.txt",
        format!("4 5\n{vertices}{plates}"),
        &["line 9", "file ends after 4 of 5 plate rows"],
    );
    expect_error(
        &dir,
        "extra.txt",
        format!("4 3\n{vertices}{plates}"),
        &["line 9", "unexpected row"],
    );
    expect_error(
        &dir,
        "negative.txt",
        counted.replacen("1 3 2", "1 -3 2", 1),
        &["line 6", "-3"],
    );
    expect_error(&dir, "layout.txt", "1 2 3 4 5\n", &["line 1", "layout"]);
    expect_error(&dir, "tag.txt", "v 0 0 0\nq 1 2 3\n", &["line 2", "'q'"]);
    let classic = format!("4\n{vertices}four\n{plates}");
    expect_error(&dir, "count.tab", classic, &["line 6", "'four'"]);
}

// ---------------------------------------------------------------------------------------
// Hostile input for every reader

fn valid_files() -> Vec<(&'static str, Vec<u8>)> {
    let (vertices, plates) = pds_rows(true, 1);
    vec![
        ("valid.obj", obj_text(&tetrahedron()).into_bytes()),
        ("valid-ascii.ply", ply_tetrahedron("ascii")),
        ("valid-le.ply", ply_tetrahedron("binary_little_endian")),
        ("valid-be.ply", ply_tetrahedron("binary_big_endian")),
        ("valid-ascii.stl", stl_ascii(&tetrahedron()).into_bytes()),
        ("valid-binary.stl", stl_binary(&tetrahedron(), b"solid")),
        (
            "valid-counted.txt",
            format!("4 4\n{vertices}{plates}").into_bytes(),
        ),
        (
            "valid-classic.tab",
            format!("4\n{vertices}4\n{plates}").into_bytes(),
        ),
    ]
}

#[test]
fn every_reader_rejects_empty_files() {
    let dir = TempDir::new("mesh-readers", "empty");
    for name in ["empty.obj", "empty.ply", "empty.stl", "empty.tab"] {
        expect_error(&dir, name, b"", &[]);
    }
}

#[test]
fn every_reader_rejects_files_cut_in_the_middle() {
    let dir = TempDir::new("mesh-readers", "cut");
    for (name, bytes) in valid_files() {
        let cut = &bytes[..bytes.len() * 2 / 3];
        let message = expect_error(&dir, &format!("cut-{name}"), cut, &[]);
        assert!(
            message.contains("line ") || message.contains("byte ") || message.contains("no facets"),
            "{message}"
        );
    }
}

/// A small xorshift generator, so that "random" corruption is reproducible.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

#[test]
fn no_reader_panics_on_prefixes_or_corrupted_bytes() {
    // Writing files is the slow part, so a sample of prefixes and corruptions is tried.
    const PREFIXES: usize = 40;
    const CORRUPTIONS: usize = 25;
    let dir = TempDir::new("mesh-readers", "prefixes");
    let mut random = XorShift(0x2545_f491_4f6c_dd1d);
    for (name, bytes) in valid_files() {
        let path = dir.join(name);
        for k in 0..PREFIXES {
            let length = (k * bytes.len() / PREFIXES + k % 7).min(bytes.len());
            std::fs::write(&path, &bytes[..length]).unwrap();
            let _ = read_mesh(&path, None);
        }
        for _ in 0..CORRUPTIONS {
            let mut corrupt = bytes.clone();
            let value = random.next();
            let at = (value % corrupt.len() as u64) as usize;
            corrupt[at] = (value >> 32) as u8;
            std::fs::write(&path, &corrupt).unwrap();
            let _ = read_mesh(&path, None);
        }
    }
}

#[test]
fn every_reader_rejects_garbage() {
    let dir = TempDir::new("mesh-readers", "garbage");
    let mut random = XorShift(88172645463325252);
    let garbage: Vec<u8> = (0..3000).map(|_| (random.next() >> 24) as u8).collect();
    for name in ["garbage.obj", "garbage.ply", "garbage.stl", "garbage.tab"] {
        expect_error(&dir, name, &garbage, &[]);
    }
}

#[test]
fn every_reader_rejects_non_finite_coordinates() {
    let dir = TempDir::new("mesh-readers", "non-finite");
    let tetra = obj_text(&tetrahedron());
    expect_error(
        &dir,
        "nan.obj",
        tetra.replacen("v 1 0 0", "v 1 NaN 0", 1),
        &["line 2", "not a finite number: 'NaN'"],
    );
    expect_error(
        &dir,
        "inf.obj",
        tetra.replacen("v 1 0 0", "v 1 0 -inf", 1),
        &["line 2", "'-inf'"],
    );
    expect_error(
        &dir,
        "inf.tab",
        tetra.replacen("v 1 0 0", "v 1 0 infinity", 1),
        &["line 2", "'infinity'"],
    );
    expect_error(
        &dir,
        "inf.stl",
        stl_ascii(&tetrahedron()).replacen("vertex 0e0", "vertex inf", 1),
        &["line 4"],
    );
    let ply = String::from_utf8(ply_tetrahedron("ascii"))
        .unwrap()
        .replacen("\n1 0 0 ", "\n1 nan 0 ", 1);
    expect_error(&dir, "nan.ply", ply, &["line 24", "finite"]);
}

#[test]
fn every_reader_rejects_out_of_range_indices() {
    let dir = TempDir::new("mesh-readers", "range");
    let tetra = obj_text(&tetrahedron());
    let bad = tetra.replacen("f 2 3 4", "f 2 3 812", 1);
    expect_error(
        &dir,
        "range.obj",
        &bad,
        &[
            "line 8",
            "face index 812 out of range (file has 4 vertices)",
        ],
    );
    expect_error(
        &dir,
        "range.tab",
        &bad,
        &[
            "line 8",
            "face index 812 out of range (file has 4 vertices)",
        ],
    );
    let ply = String::from_utf8(ply_tetrahedron("ascii"))
        .unwrap()
        .replacen("1 3 1 2 3", "1 3 1 2 4", 1);
    expect_error(
        &dir,
        "range.ply",
        ply,
        &["line 32", "face index 4 out of range"],
    );
}

#[test]
fn huge_header_counts_fail_fast_without_allocating() {
    let dir = TempDir::new("mesh-readers", "huge");
    let started = std::time::Instant::now();
    let ply = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n\
               property float y\nproperty float z\nelement face 4000000000\n\
               property list uint int vertex_indices\nend_header\n\0\0\0\0\0\0";
    expect_error(
        &dir,
        "huge.ply",
        ply,
        &["file ends after 0 of 4000000000 'vertex' elements"],
    );
    let ply_ascii = ply
        .replace("binary_little_endian", "ascii")
        .replace("\0", "1 ");
    expect_error(
        &dir,
        "huge-ascii.ply",
        ply_ascii,
        &["line 10", "file ends after 2 of 4000000000"],
    );
    let list = b"ply\nformat binary_big_endian 1.0\nelement vertex 0\nproperty float x\n\
                property float y\nproperty float z\nelement face 1\n\
                property list uint int vertex_indices\nend_header\n\xff\xff\xff\xff\0\0\0\0";
    expect_error(
        &dir,
        "huge-list.ply",
        list,
        &["file ends after 0 of 1 'face' elements"],
    );
    let empty_element = "ply\nformat ascii 1.0\nelement nothing 18446744073709551615\n\
                         element vertex 0\nproperty float x\nproperty float y\nproperty float z\n\
                         element face 0\nproperty list uchar int vertex_indices\nend_header\n";
    expect_error(&dir, "empty-element.ply", empty_element, &["no facets"]);
    let mut stl = vec![b'x'; 80];
    stl.extend(u32::MAX.to_le_bytes());
    stl.extend([0u8; 60]);
    expect_error(
        &dir,
        "huge.stl",
        stl,
        &["byte 134", "file ends after 1 of 4294967295 facets"],
    );
    expect_error(
        &dir,
        "huge.txt",
        "99999999999999 99999999999999\n0 0 0\n",
        &["line 2", "file ends after 1 of 99999999999999 vertex rows"],
    );
    expect_error(&dir, "huge.tab", "18446744073709551616\n", &["line 1"]);
    assert!(
        started.elapsed().as_secs_f64() < 2.0,
        "took {:?}",
        started.elapsed()
    );
}

#[test]
fn format_can_be_forced_and_unknown_extensions_fail() {
    let dir = TempDir::new("mesh-readers", "format");
    let path = write(&dir, "shape.mesh", obj_text(&tetrahedron()));
    assert!(read_mesh(&path, None)
        .unwrap_err()
        .to_string()
        .contains("unknown mesh format"));
    assert_eq!(
        read_mesh(&path, Some(MeshFormat::Obj)).unwrap(),
        tetrahedron()
    );
    assert_eq!(
        read_mesh(&path, Some(MeshFormat::Pds)).unwrap(),
        tetrahedron()
    );
}

// ---------------------------------------------------------------------------------------
// Real shapes

#[test]
fn real_shapes_load_with_expected_counts() {
    let expected = [
        ("phobos/m1phobos.obj", 16471, 32070),
        ("itokawa/ItokawaHayabusa.obj", 25350, 49152),
        ("itokawa/itokawa_8.obj", 386, 768),
        ("itokawa/itokawa_16.obj", 1538, 3072),
        ("itokawa/itokawa_32.obj", 6146, 12288),
        ("eros/EROS856Vert1708Fac.txt", 856, 1708),
        ("eros/eros_64.obj", 25350, 49152),
        ("deimos/DEIMOS_K005_THO_V01_from_dsk.obj", 2664, 5184),
        ("moon/haworth5412.obj", 2791, 5412),
        ("vesta/4vesta.obj", 2699, 5040),
    ];
    for (file, vertices, facets) in expected {
        let mesh = read(&shape(file));
        assert_eq!(
            (mesh.vertices.len(), mesh.triangles.len()),
            (vertices, facets),
            "{file}"
        );
    }
}

fn real_report(file: &str) -> MeshReport {
    let report = inspect(&Mesh::from_raw(read(&shape(file)), LengthUnit::Km));
    println!("{file}:\n{report}");
    report
}

#[test]
fn itokawa_16_is_closed_outward_and_not_convex() {
    let r = real_report("itokawa/itokawa_16.obj");
    assert!(r.closed);
    assert_eq!(
        (r.boundary_edges, r.non_manifold_edges, r.inconsistent_edges),
        (0, 0, 0)
    );
    assert!(r.signed_volume_m3 > 0.0);
    assert!(!r.convex);
    assert!(r.problems().is_empty(), "{:?}", r.problems());
}

#[test]
fn itokawa_hayabusa_has_unreferenced_vertices() {
    let r = real_report("itokawa/ItokawaHayabusa.obj");
    assert_eq!(r.unreferenced_vertices, 772);
    assert!(r.problems().iter().any(|p| p.contains("772")));
}

#[test]
fn phobos_is_open_along_its_duplicated_vertices() {
    // Independently checked: 152 edges are used by one facet (none by more than two),
    // and 360 duplicated vertices are unused.
    let r = real_report("phobos/m1phobos.obj");
    assert_eq!((r.boundary_edges, r.non_manifold_edges), (152, 0));
    assert_eq!(r.unreferenced_vertices, 360);
    assert!(!r.closed && !r.convex);
}

#[test]
fn deimos_dsk_has_degenerate_plates_at_its_poles() {
    // Each pole is a ring of 72 distinct vertices at one position: 144 zero-area plates,
    // and the ring edges are used by one plate each.
    let r = real_report("deimos/DEIMOS_K005_THO_V01_from_dsk.obj");
    assert_eq!(r.degenerate_facets, 144);
    assert_eq!(
        (r.boundary_edges, r.non_manifold_edges, r.inconsistent_edges),
        (144, 0, 0)
    );
    assert!(r.signed_volume_m3 > 0.0);
}

#[test]
fn haworth_terrain_is_open() {
    let r = real_report("moon/haworth5412.obj");
    assert_eq!(r.boundary_edges, 168);
    assert!(!r.closed);
    assert!(!r.convex);
}

// ---------------------------------------------------------------------------------------
// Inspection of generated shapes

#[test]
fn cube_and_octahedron_are_convex_and_clean() {
    for (name, raw, volume) in [
        ("cube", cube(), 1.0),
        ("octahedron", octahedron(), 4.0 / 3.0),
    ] {
        let r = report(raw);
        assert!(r.convex && r.closed, "{name}: {r}");
        assert!((r.signed_volume_m3 - volume).abs() < 1e-12, "{name}: {r}");
        assert_eq!(r.problems(), Vec::<String>::new(), "{name}");
        assert!(r.to_string().contains("ok: convex"), "{name}: {r}");
    }
    let r = report(cube());
    assert_eq!(r.extent_m, [1.0, 1.0, 1.0]);
    assert!((r.total_area_m2 - 6.0).abs() < 1e-12);
    // 12 unit edges and 6 face diagonals.
    assert!((r.mean_edge_m - (12.0 + 6.0 * 2f64.sqrt()) / 18.0).abs() < 1e-12);
}

#[test]
fn a_cube_scaled_to_kilometres_stays_convex() {
    let r = inspect(&Mesh::from_raw(cube(), LengthUnit::Km));
    assert!(r.convex);
    assert!((r.signed_volume_m3 - 1e9).abs() < 1e-3);
}

#[test]
fn a_cube_with_one_flipped_facet_has_inconsistent_edges() {
    let mut raw = cube();
    raw.triangles[0].swap(1, 2);
    let r = report(raw);
    assert_eq!(r.inconsistent_edges, 3);
    assert!(r.closed && !r.convex);
    assert!(r.to_string().contains("problem: 3 edges"), "{r}");
}

#[test]
fn an_inside_out_cube_has_negative_volume_and_says_how_to_fix_it() {
    let mut raw = cube();
    raw.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    let r = report(raw);
    assert!(r.signed_volume_m3 < 0.0 && !r.convex && r.closed);
    assert_eq!(r.inconsistent_edges, 0);
    assert!(r.to_string().contains("orient = \"outward\""), "{r}");
    assert!(r
        .problems()
        .iter()
        .any(|p| p.contains("orient = \"outward\"")));
}

#[test]
fn an_open_box_has_boundary_edges() {
    let mut raw = cube();
    raw.triangles.truncate(10);
    let r = report(raw);
    assert_eq!(r.boundary_edges, 4);
    assert!(!r.closed && !r.convex);
}

#[test]
fn a_concave_closed_mesh_is_not_convex() {
    // Push one cube corner inward past the opposite face diagonal.
    let mut raw = cube();
    raw.vertices[7] = DVec3::splat(0.3);
    let r = report(raw);
    assert!(r.closed && r.signed_volume_m3 > 0.0 && !r.convex, "{r}");
}

#[test]
fn two_separate_cubes_are_not_convex() {
    let mut raw = cube();
    let second = cube();
    let offset = raw.vertices.len() as u32;
    raw.vertices
        .extend(second.vertices.iter().map(|v| *v + DVec3::X * 3.0));
    raw.triangles
        .extend(second.triangles.iter().map(|t| t.map(|i| i + offset)));
    let r = report(raw);
    assert!(r.closed && !r.convex);
}

#[test]
fn degenerate_and_unreferenced_are_counted() {
    let mut raw = tetrahedron();
    raw.vertices.push(DVec3::splat(9.0));
    raw.triangles.push([0, 0, 1]);
    raw.triangles.push([0, 1, 1]);
    let r = report(raw);
    assert_eq!((r.unreferenced_vertices, r.degenerate_facets), (1, 2));
    // Facets with a repeated vertex are left out of the edge topology.
    assert!(r.closed, "{r}");
    assert!(!r.convex);
}

/// A million-facet torus is inspected whole: closed, not convex, consistently oriented.
/// (How long it takes is a benchmark question, not a test's: `slim info` on a large mesh.)
#[test]
fn inspecting_a_million_facets_finds_a_closed_torus() {
    // A 500 × 1000 grid wrapped into a torus: closed, 1M facets.
    let (n, m) = (500u32, 1000u32);
    let mut raw = RawMesh::default();
    for i in 0..n {
        for j in 0..m {
            let (u, v) = (f64::from(i) / f64::from(n), f64::from(j) / f64::from(m));
            let (su, cu) = (u * std::f64::consts::TAU).sin_cos();
            let (sv, cv) = (v * std::f64::consts::TAU).sin_cos();
            raw.vertices
                .push(DVec3::new((3.0 + cv) * cu, (3.0 + cv) * su, sv));
        }
    }
    let at = |i: u32, j: u32| (i % n) * m + (j % m);
    for i in 0..n {
        for j in 0..m {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
            raw.triangles.push([a, b, c]);
            raw.triangles.push([a, c, d]);
        }
    }
    let mesh = Mesh::from_raw(raw, LengthUnit::M);
    let r = inspect(&mesh);
    assert_eq!(r.facets, 1_000_000);
    assert!(r.closed && !r.convex);
    assert_eq!(r.inconsistent_edges, 0);
}

/// The topology of every real shape, as measured (and cross-checked by an independent
/// script): (file, unreferenced, degenerate, boundary, non-manifold, inconsistent,
/// volume sign, convex).
#[test]
fn real_shapes_have_the_measured_topology() {
    let expected = [
        ("phobos/m1phobos.obj", 360, 0, 152, 0, 0, 1.0, false),
        ("itokawa/ItokawaHayabusa.obj", 772, 0, 0, 0, 0, 1.0, false),
        ("itokawa/itokawa_8.obj", 0, 0, 0, 0, 0, 1.0, false),
        ("itokawa/itokawa_16.obj", 0, 0, 0, 0, 0, 1.0, false),
        ("itokawa/itokawa_32.obj", 0, 0, 0, 0, 0, 1.0, false),
        ("eros/EROS856Vert1708Fac.txt", 0, 0, 0, 0, 0, 1.0, false),
        ("eros/eros_64.obj", 772, 0, 0, 0, 0, 1.0, false),
        (
            "deimos/DEIMOS_K005_THO_V01_from_dsk.obj",
            0,
            144,
            144,
            0,
            0,
            1.0,
            false,
        ),
        ("moon/haworth5412.obj", 0, 0, 168, 0, 0, -1.0, false),
        ("vesta/4vesta.obj", 0, 0, 356, 0, 0, 1.0, false),
    ];
    for (file, unreferenced, degenerate, boundary, non_manifold, inconsistent, sign, convex) in
        expected
    {
        let r = real_report(file);
        let measured = (
            r.unreferenced_vertices,
            r.degenerate_facets,
            r.boundary_edges,
            r.non_manifold_edges,
            r.inconsistent_edges,
            r.signed_volume_m3.signum(),
            r.convex,
        );
        assert_eq!(
            measured,
            (
                unreferenced,
                degenerate,
                boundary,
                non_manifold,
                inconsistent,
                sign,
                convex
            ),
            "{file}"
        );
        assert_eq!(r.closed, boundary == 0 && non_manifold == 0, "{file}");
    }
}

/// A text file saved with a UTF-8 byte-order mark reads exactly like the same file
/// without it: an OBJ used to lose its first vertex line and run with the wrong geometry.
#[test]
fn every_text_mesh_reads_the_same_with_a_byte_order_mark() {
    let dir = TempDir::new("mesh-readers", "bom");
    let (vertices, plates) = pds_rows(false, 0);
    let texts = [
        ("obj", obj_text(&tetrahedron()).into_bytes()),
        ("ply", ply_tetrahedron("ascii")),
        ("stl", stl_ascii(&tetrahedron()).into_bytes()),
        ("txt", format!("4 4\n{vertices}{plates}").into_bytes()),
    ];
    for (ext, text) in texts {
        let plain = read(&write(&dir, &format!("plain.{ext}"), &text));
        let mut marked = b"\xEF\xBB\xBF".to_vec();
        marked.extend(&text);
        let with_bom = read(&write(&dir, &format!("bom.{ext}"), marked));
        assert_eq!(with_bom, plain, "{ext}");
        assert_eq!(with_bom.vertices.len(), 4, "{ext}");
    }
}

/// Finite coordinates so large that areas and normals overflow (1e200) are refused with
/// the vertex, instead of a mesh with NaN areas and normals that runs to exit 0.
#[test]
fn coordinates_whose_squares_overflow_are_refused() {
    let dir = TempDir::new("mesh-readers", "huge-coordinates");
    let mut mesh = tetrahedron();
    mesh.vertices[2].y = 1e200;
    let message = expect_error(&dir, "far.obj", obj_text(&mesh), &["vertex 3", "1e100"]);
    assert!(message.contains("overflow"), "{message}");
    mesh.vertices[2].y = 1e90;
    let near_enough = read(&write(&dir, "near.obj", obj_text(&mesh)));
    assert_eq!(near_enough.vertices[2].y, 1e90);
}
