//! Stanford PLY reader (ASCII, binary little-endian and binary big-endian).
//!
//! In: the bytes of a PLY file. Out: a [`RawMesh`] with the `x y z` properties of the
//! `vertex` element (any numeric type) and the `vertex_indices` (or `vertex_index`) list
//! of the `face` element, polygons fan-triangulated, in file order. Every other element
//! and property, lists included, is read past and ignored.

use super::obj::fan_triangulate;
use super::obj::text::{quoted, LargestIndex};
use super::RawMesh;
use crate::error::{Error, Result};
use glam::DVec3;
use std::path::Path;

/// Parses a PLY file.
pub(super) fn parse(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    let header = Header::parse(path, bytes)?;
    let body = bytes.get(header.body_start..).unwrap_or_default();
    let mut reader: Box<dyn Body + '_> = match header.encoding {
        Encoding::Ascii => Box::new(AsciiBody::new(body, header.body_first_line)),
        Encoding::Binary { big_endian } => Box::new(BinaryBody {
            bytes: body,
            position: 0,
            file_offset: header.body_start as u64,
            big_endian,
        }),
    };
    let mut mesh = MeshBuilder::default();
    for element in &header.elements {
        read_element(element, reader.as_mut(), body.len(), &mut mesh)
            .map_err(|e| e.into_error(path))?;
    }
    if reader.has_more() {
        return Err(reader
            .location()
            .error(path, "unexpected data after the last element of the header"));
    }
    mesh.finish(path)
}

/// A scalar type of a PLY property.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn from_name(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Binary { big_endian: bool },
}

#[derive(Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

/// What the reader does with a property's values.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Ignore,
    Coordinate(usize),
    FaceIndices,
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
    role: Role,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: u64,
    properties: Vec<Property>,
    /// 1-based header line of the `element` statement, for errors about the element.
    line: usize,
}

impl Element {
    fn is_vertex(&self) -> bool {
        self.name == "vertex"
    }

    fn is_face(&self) -> bool {
        self.name == "face"
    }

    /// The fewest bytes one instance takes in a binary body (lists may be empty).
    fn min_binary_size(&self) -> usize {
        self.properties
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) | Kind::List { count: s, .. } => s.size(),
            })
            .sum()
    }
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    body_start: usize,
    body_first_line: usize,
}

impl Header {
    fn parse(path: &Path, bytes: &[u8]) -> Result<Header> {
        if !bytes.starts_with(b"ply") {
            return Err(Error::file(
                path,
                "not a PLY file: it does not start with 'ply'",
            ));
        }
        let mut encoding = None;
        let mut elements: Vec<Element> = Vec::new();
        let mut line_start = 0;
        let mut line_number = 0;
        while line_start < bytes.len() {
            line_number += 1;
            let line_end = bytes[line_start..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(bytes.len(), |p| line_start + p);
            let next_start = (line_end + 1).min(bytes.len());
            let line = String::from_utf8_lossy(&bytes[line_start..line_end]);
            let at = |msg: String| Error::at_line(path, line_number, msg);
            let mut words = line.split_ascii_whitespace();
            match words.next() {
                Some("ply") if line_number == 1 => {}
                Some("comment" | "obj_info") | None => {}
                Some("format") => encoding = Some(parse_format(words).map_err(at)?),
                Some("element") => elements.push(parse_element(words, line_number).map_err(at)?),
                Some("property") => {
                    let element = elements
                        .last_mut()
                        .ok_or_else(|| at("property declared before any element".to_string()))?;
                    let property = parse_property(words, element).map_err(at)?;
                    element.properties.push(property);
                }
                Some("end_header") => {
                    let encoding = encoding.ok_or_else(|| {
                        at("header has no 'format' line before 'end_header'".to_string())
                    })?;
                    check_mesh_elements(&elements).map_err(|msg| Error::file(path, msg))?;
                    return Ok(Header {
                        encoding,
                        elements,
                        body_start: next_start,
                        body_first_line: line_number + 1,
                    });
                }
                Some(other) => {
                    return Err(at(format!("unknown header keyword '{}'", shorten(other))));
                }
            }
            line_start = next_start;
        }
        Err(Error::file(
            path,
            "the PLY header has no 'end_header' line (truncated file?)",
        ))
    }
}

/// A header word as an error message quotes it: shortened, control bytes escaped.
fn shorten(word: &str) -> String {
    crate::error::printable(word, 40)
}

fn parse_format<'a>(mut words: impl Iterator<Item = &'a str>) -> Result<Encoding, String> {
    let encoding = match words.next() {
        Some("ascii") => Encoding::Ascii,
        Some("binary_little_endian") => Encoding::Binary { big_endian: false },
        Some("binary_big_endian") => Encoding::Binary { big_endian: true },
        other => {
            return Err(format!(
                "unknown format '{}': expected ascii, binary_little_endian or binary_big_endian",
                shorten(other.unwrap_or_default())
            ))
        }
    };
    match words.next() {
        Some("1.0" | "1") => Ok(encoding),
        other => Err(format!(
            "unsupported PLY version '{}': only 1.0 exists",
            shorten(other.unwrap_or_default())
        )),
    }
}

fn parse_element<'a>(
    mut words: impl Iterator<Item = &'a str>,
    line: usize,
) -> Result<Element, String> {
    let (Some(name), Some(count), None) = (words.next(), words.next(), words.next()) else {
        return Err("expected 'element NAME COUNT'".to_string());
    };
    let count = count.parse::<u64>().map_err(|_| {
        format!(
            "element count is not a non-negative integer: '{}'",
            shorten(count)
        )
    })?;
    Ok(Element {
        name: name.to_string(),
        count,
        properties: Vec::new(),
        line,
    })
}

fn parse_property<'a>(
    mut words: impl Iterator<Item = &'a str>,
    element: &Element,
) -> Result<Property, String> {
    let scalar = |word: Option<&str>| {
        let word = word.unwrap_or_default();
        Scalar::from_name(word).ok_or_else(|| format!("unknown property type '{}'", shorten(word)))
    };
    let first = words.next();
    let (kind, name) = if first == Some("list") {
        let count = scalar(words.next())?;
        if matches!(count, Scalar::F32 | Scalar::F64) {
            return Err("a list count type must be an integer type".to_string());
        }
        let item = scalar(words.next())?;
        (Kind::List { count, item }, words.next())
    } else {
        (Kind::Scalar(scalar(first)?), words.next())
    };
    let (Some(name), None) = (name, words.next()) else {
        return Err("expected 'property TYPE NAME' or 'property list COUNT ITEM NAME'".into());
    };
    let role = match (&kind, name) {
        (Kind::Scalar(_), "x") if element.is_vertex() => Role::Coordinate(0),
        (Kind::Scalar(_), "y") if element.is_vertex() => Role::Coordinate(1),
        (Kind::Scalar(_), "z") if element.is_vertex() => Role::Coordinate(2),
        (Kind::List { .. }, "vertex_indices" | "vertex_index") if element.is_face() => {
            Role::FaceIndices
        }
        _ => Role::Ignore,
    };
    if role != Role::Ignore && element.properties.iter().any(|p| p.role == role) {
        return Err(format!("property '{name}' declared twice"));
    }
    Ok(Property {
        name: name.to_string(),
        kind,
        role,
    })
}

/// The header must describe a mesh: vertices with x, y, z and faces with an index list.
fn check_mesh_elements(elements: &[Element]) -> Result<(), String> {
    let vertex = elements
        .iter()
        .find(|e| e.is_vertex())
        .ok_or("the header declares no 'vertex' element")?;
    for (axis, name) in ["x", "y", "z"].iter().enumerate() {
        if !vertex
            .properties
            .iter()
            .any(|p| p.role == Role::Coordinate(axis))
        {
            return Err(format!(
                "the 'vertex' element (header line {}) has no scalar property '{name}'",
                vertex.line
            ));
        }
    }
    let face = elements
        .iter()
        .find(|e| e.is_face())
        .ok_or("the header declares no 'face' element")?;
    if !face.properties.iter().any(|p| p.role == Role::FaceIndices) {
        return Err(format!(
            "the 'face' element (header line {}) has no list property 'vertex_indices'",
            face.line
        ));
    }
    Ok(())
}

/// Where in the file a value was read: binary bodies report byte offsets, ASCII lines.
#[derive(Debug, Clone, Copy)]
enum Location {
    Line(usize),
    Byte(u64),
}

impl Location {
    fn error(self, path: &Path, msg: impl Into<String>) -> Error {
        match self {
            Location::Line(line) => Error::at_line(path, line, msg),
            Location::Byte(offset) => Error::at_byte(path, offset, msg),
        }
    }
}

/// A body read failure, before the element context is added.
enum ValueError {
    /// The body ends before the value.
    End(Location),
    /// The value is malformed.
    Bad(Location, String),
}

/// An element read failure: location and the complete message.
struct ElementError(Location, String);

impl ElementError {
    fn into_error(self, path: &Path) -> Error {
        self.0.error(path, self.1)
    }
}

/// The values of a PLY body, in order, whatever the encoding.
trait Body {
    /// The next value, of type `scalar`, as f64 (exact for every PLY type), and where
    /// it starts.
    fn next(&mut self, scalar: Scalar) -> Result<(f64, Location), ValueError>;
    /// Where the next value starts.
    fn location(&self) -> Location;
    /// True when data is left after the current position.
    fn has_more(&mut self) -> bool;
}

struct BinaryBody<'a> {
    bytes: &'a [u8],
    position: usize,
    file_offset: u64,
    big_endian: bool,
}

impl BinaryBody<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], ValueError> {
        let end = self.position.checked_add(N);
        let slice = end.and_then(|end| self.bytes.get(self.position..end));
        let mut array = slice
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or(ValueError::End(self.location()))?;
        self.position += N;
        if self.big_endian {
            array.reverse();
        }
        Ok(array)
    }
}

impl Body for BinaryBody<'_> {
    fn next(&mut self, scalar: Scalar) -> Result<(f64, Location), ValueError> {
        let at = self.location();
        // Bytes are turned little-endian by `take`.
        let value = match scalar {
            Scalar::I8 => f64::from(i8::from_le_bytes(self.take()?)),
            Scalar::U8 => f64::from(u8::from_le_bytes(self.take()?)),
            Scalar::I16 => f64::from(i16::from_le_bytes(self.take()?)),
            Scalar::U16 => f64::from(u16::from_le_bytes(self.take()?)),
            Scalar::I32 => f64::from(i32::from_le_bytes(self.take()?)),
            Scalar::U32 => f64::from(u32::from_le_bytes(self.take()?)),
            Scalar::F32 => f64::from(f32::from_le_bytes(self.take()?)),
            Scalar::F64 => f64::from_le_bytes(self.take()?),
        };
        Ok((value, at))
    }

    fn location(&self) -> Location {
        Location::Byte(self.file_offset + self.position as u64)
    }

    fn has_more(&mut self) -> bool {
        self.position < self.bytes.len()
    }
}

/// Whitespace-separated tokens; PLY allows elements to span or share lines.
struct AsciiBody<'a> {
    /// The unread part of the body, starting on line `line`.
    rest: &'a [u8],
    line: usize,
}

impl<'a> AsciiBody<'a> {
    fn new(body: &'a [u8], first_line: usize) -> Self {
        AsciiBody {
            rest: body,
            line: first_line,
        }
    }

    fn next_token(&mut self) -> Option<&'a [u8]> {
        let start = self.rest.iter().position(|b| !b.is_ascii_whitespace())?;
        self.line += self.rest[..start].iter().filter(|&&b| b == b'\n').count();
        let token_and_rest = &self.rest[start..];
        let length = token_and_rest
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(token_and_rest.len());
        let (token, rest) = token_and_rest.split_at(length);
        self.rest = rest;
        Some(token)
    }
}

impl Body for AsciiBody<'_> {
    fn next(&mut self, scalar: Scalar) -> Result<(f64, Location), ValueError> {
        let token = self.next_token().ok_or(ValueError::End(self.location()))?;
        let at = self.location();
        let integral = !matches!(scalar, Scalar::F32 | Scalar::F64);
        let value = std::str::from_utf8(token)
            .ok()
            .and_then(|text| text.parse::<f64>().ok())
            .filter(|value| !integral || value.fract() == 0.0);
        let expected = if integral { "an integer" } else { "a number" };
        let value = value.ok_or_else(|| {
            ValueError::Bad(at, format!("expected {expected}, found {}", quoted(token)))
        })?;
        Ok((value, at))
    }

    fn location(&self) -> Location {
        Location::Line(self.line)
    }

    fn has_more(&mut self) -> bool {
        self.next_token().is_some()
    }
}

/// Vertices and triangles gathered from the body.
#[derive(Default)]
struct MeshBuilder {
    mesh: RawMesh,
    polygon: Vec<u32>,
    /// The largest vertex index used and where, checked once all elements are read.
    largest_index: LargestIndex<Location>,
}

impl MeshBuilder {
    fn finish(self, path: &Path) -> Result<RawMesh> {
        self.largest_index
            .check(self.mesh.vertices.len(), 0, 0, |at, msg| {
                at.error(path, msg)
            })?;
        Ok(self.mesh)
    }
}

fn read_element(
    element: &Element,
    body: &mut dyn Body,
    body_len: usize,
    mesh: &mut MeshBuilder,
) -> Result<(), ElementError> {
    if element.properties.is_empty() {
        // Nothing to read, however large the count.
        return Ok(());
    }
    let plausible = (body_len / element.min_binary_size().max(1)) as u64;
    let reserve = element.count.min(plausible) as usize;
    if element.is_vertex() {
        mesh.mesh.vertices.reserve(reserve);
    } else if element.is_face() {
        mesh.mesh.triangles.reserve(reserve);
    }
    for instance in 0..element.count {
        read_instance(element, body, mesh).map_err(|e| match e {
            ValueError::End(at) => ElementError(
                at,
                format!(
                    "file ends after {instance} of {} '{}' elements",
                    element.count,
                    shorten(&element.name)
                ),
            ),
            ValueError::Bad(at, msg) => {
                let name = shorten(&element.name);
                ElementError(at, format!("'{name}' element {instance}: {msg}"))
            }
        })?;
    }
    Ok(())
}

fn read_instance(
    element: &Element,
    body: &mut dyn Body,
    mesh: &mut MeshBuilder,
) -> Result<(), ValueError> {
    let mut xyz = [0.0; 3];
    mesh.polygon.clear();
    for property in &element.properties {
        match property.kind {
            Kind::Scalar(scalar) => {
                let (value, at) = body.next(scalar)?;
                if let Role::Coordinate(axis) = property.role {
                    if !value.is_finite() {
                        return Err(ValueError::Bad(
                            at,
                            format!(
                                "coordinate {} is not a finite number: {value}",
                                property.name
                            ),
                        ));
                    }
                    xyz[axis] = value;
                }
            }
            Kind::List { count, item } => {
                let (length, at) = body.next(count)?;
                if length < 0.0 {
                    return Err(ValueError::Bad(
                        at,
                        format!(
                            "list '{}' has negative length {length}",
                            shorten(&property.name)
                        ),
                    ));
                }
                for _ in 0..length as u64 {
                    let (value, at) = body.next(item)?;
                    if property.role == Role::FaceIndices {
                        let index = vertex_index(value).map_err(|msg| ValueError::Bad(at, msg))?;
                        mesh.largest_index.note(index, at);
                        mesh.polygon.push(index);
                    }
                }
                if property.role == Role::FaceIndices && mesh.polygon.len() < 3 {
                    return Err(ValueError::Bad(
                        at,
                        format!(
                            "face has {} vertices; at least 3 needed",
                            mesh.polygon.len()
                        ),
                    ));
                }
            }
        }
    }
    if element.is_vertex() {
        mesh.mesh.vertices.push(DVec3::from_array(xyz));
    } else if element.is_face() {
        fan_triangulate(&mesh.polygon, &mut mesh.mesh.triangles);
    }
    Ok(())
}

fn vertex_index(value: f64) -> Result<u32, String> {
    if value.fract() == 0.0 && (0.0..=f64::from(u32::MAX)).contains(&value) {
        Ok(value as u32)
    } else {
        Err(format!("invalid vertex index {value}"))
    }
}
