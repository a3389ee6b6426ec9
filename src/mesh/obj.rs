//! Wavefront OBJ reader.
//!
//! In: the bytes of an OBJ file. Out: a [`RawMesh`] with every `v` position (in file
//! order) and every `f` polygon fan-triangulated into 0-based triangles (in file order).
//! Texture and normal references (`i/t`, `i//n`, `i/t/n`) and negative (relative)
//! indices are resolved to the position index. Every other statement (vt, vn, vp,
//! mtllib, usemtl, o, g, s, l, and the many unknown ones) is ignored.
//!
//! The [`text`] submodule holds the line, token and number helpers shared with the PDS
//! plate reader.

use super::RawMesh;
use crate::error::{Error, Result};
use glam::DVec3;
use std::path::Path;
use text::Row;

/// Parses an OBJ file.
pub(super) fn parse(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    let mut mesh = RawMesh::default();
    let mut polygon = Vec::new();
    let mut largest = text::LargestIndex::default();
    for row in text::rows(bytes) {
        let mut tokens = row.tokens();
        match tokens.next() {
            Some(b"v") => mesh.vertices.push(vertex(path, &row, tokens)?),
            Some(b"f") => {
                polygon.clear();
                for token in tokens {
                    let index = face_index(path, &row, token, mesh.vertices.len())?;
                    largest.note(index, row.line);
                    polygon.push(index);
                }
                if polygon.len() < 3 {
                    return Err(row.error(
                        path,
                        format!("face has {} vertices; at least 3 needed", polygon.len()),
                    ));
                }
                fan_triangulate(&polygon, &mut mesh.triangles);
            }
            // OBJ has many statements that carry no surface geometry.
            _ => {}
        }
    }
    largest.check(mesh.vertices.len(), 0, 1, |line, msg| {
        Error::at_line(path, line, msg)
    })?;
    Ok(mesh)
}

/// Splits a convex (or at least star-shaped from its first corner) polygon into
/// triangles sharing the first corner, keeping the polygon's winding.
pub(super) fn fan_triangulate(polygon: &[u32], triangles: &mut Vec<[u32; 3]>) {
    if let Some((&first, rest)) = polygon.split_first() {
        triangles.extend(rest.windows(2).map(|pair| [first, pair[0], pair[1]]));
    }
}

/// The position of a `v x y z [w]` statement; w and vertex colours are ignored.
fn vertex<'a>(path: &Path, row: &Row, mut tokens: impl Iterator<Item = &'a [u8]>) -> Result<DVec3> {
    let mut xyz = [0.0; 3];
    for (found, coordinate) in xyz.iter_mut().enumerate() {
        let token = tokens.next().ok_or_else(|| {
            row.error(
                path,
                format!("vertex has {found} coordinates; 3 (x y z) needed"),
            )
        })?;
        *coordinate = text::coordinate(token).map_err(|msg| row.error(path, msg))?;
    }
    Ok(DVec3::from_array(xyz))
}

/// The 0-based position index of one face corner `i`, `i/t`, `i//n` or `i/t/n`.
///
/// Indices past the vertices read so far are allowed (a file may define vertices after
/// the faces using them) and checked once the whole file is read.
fn face_index(path: &Path, row: &Row, token: &[u8], vertices_so_far: usize) -> Result<u32> {
    let position = token.split(|&b| b == b'/').next().unwrap_or_default();
    let index = text::integer(position).map_err(|msg| row.error(path, msg))?;
    let zero_based = match index {
        0 => return Err(row.error(path, "face index 0 is invalid: OBJ indices start at 1")),
        i if i > 0 => i - 1,
        relative => {
            let resolved = vertices_so_far as i64 + relative;
            if resolved < 0 {
                return Err(row.error(
                    path,
                    format!(
                        "relative face index {relative} points before the first vertex \
                         ({vertices_so_far} vertices read so far)"
                    ),
                ));
            }
            resolved
        }
    };
    u32::try_from(zero_based)
        .map_err(|_| row.error(path, format!("face index {index} does not fit in 32 bits")))
}

/// Line, token and number helpers for the whitespace-separated text formats.
pub(super) mod text {
    use crate::error::{Error, Result};
    use std::path::Path;

    /// One non-blank line of a text file with its `#` comment removed.
    pub(in crate::mesh) struct Row<'a> {
        /// 1-based line number in the file.
        pub line: usize,
        /// The line's content before any `#`, without surrounding whitespace.
        pub content: &'a [u8],
    }

    impl<'a> Row<'a> {
        /// The whitespace-separated tokens of the row.
        pub fn tokens(&self) -> impl Iterator<Item = &'a [u8]> + 'a {
            self.content
                .split(|b| b.is_ascii_whitespace())
                .filter(|token| !token.is_empty())
        }

        /// The first `N` tokens (empty slices where the row is shorter) and the row's
        /// total token count, without allocating.
        pub fn fields<const N: usize>(&self) -> ([&'a [u8]; N], usize) {
            let mut fields = [&[][..]; N];
            let mut count = 0;
            for token in self.tokens() {
                if let Some(field) = fields.get_mut(count) {
                    *field = token;
                }
                count += 1;
            }
            (fields, count)
        }

        /// A parse error located at this row.
        pub fn error(&self, path: &Path, msg: impl Into<String>) -> Error {
            Error::at_line(path, self.line, msg)
        }
    }

    /// The rows of a text file that hold data: lines split at `\n` (a trailing `\r` is
    /// whitespace, so CRLF files read the same), `#` comments removed, blank rows
    /// skipped. Bytes are not required to be UTF-8 outside the tokens that are parsed.
    pub(in crate::mesh) fn rows(bytes: &[u8]) -> impl Iterator<Item = Row<'_>> {
        bytes
            .split(|&b| b == b'\n')
            .enumerate()
            .filter_map(|(index, line)| {
                let before_comment = line.split(|&b| b == b'#').next().unwrap_or_default();
                let content = before_comment.trim_ascii();
                (!content.is_empty()).then_some(Row {
                    line: index + 1,
                    content,
                })
            })
    }

    /// The 1-based number of the last line of the file, for "file ends early" errors.
    pub(in crate::mesh) fn last_line(bytes: &[u8]) -> usize {
        let newlines = bytes.iter().filter(|&&b| b == b'\n').count();
        if bytes.ends_with(b"\n") {
            newlines.max(1)
        } else {
            newlines + 1
        }
    }

    /// A token as it should appear in an error message: lossy UTF-8, shortened, control
    /// bytes escaped (a broken file's NUL or escape sequence must not reach a terminal or
    /// split the message's line).
    pub(in crate::mesh) fn quoted(token: &[u8]) -> String {
        const LONGEST: usize = 40;
        let text = String::from_utf8_lossy(token);
        format!("'{}'", crate::error::printable(&text, LONGEST))
    }

    /// A finite coordinate. Fortran `D` exponents (`1.5D+02`), still found in old plate
    /// files, are accepted.
    pub(in crate::mesh) fn coordinate(token: &[u8]) -> Result<f64, String> {
        let value = std::str::from_utf8(token)
            .ok()
            .and_then(|text| {
                text.parse::<f64>()
                    .ok()
                    .or_else(|| text.replace(['D', 'd'], "E").parse::<f64>().ok())
            })
            .ok_or_else(|| format!("expected a number, found {}", quoted(token)))?;
        if value.is_finite() {
            Ok(value)
        } else {
            Err(format!(
                "coordinate is not a finite number: {}",
                quoted(token)
            ))
        }
    }

    /// A (possibly negative) integer such as a vertex index or a count.
    pub(in crate::mesh) fn integer(token: &[u8]) -> Result<i64, String> {
        std::str::from_utf8(token)
            .ok()
            .and_then(|text| text.parse::<i64>().ok())
            .ok_or_else(|| format!("expected an integer, found {}", quoted(token)))
    }

    /// The largest vertex index of a file and where it is (a line, or a byte offset in
    /// binary files), so that indices can be range-checked once the vertex count is
    /// known without storing a location per facet.
    pub(in crate::mesh) struct LargestIndex<At> {
        largest: Option<(u32, At)>,
    }

    impl<At> Default for LargestIndex<At> {
        fn default() -> Self {
            LargestIndex { largest: None }
        }
    }

    impl<At: Copy> LargestIndex<At> {
        /// Records `index` (as stored, before any base shift) found at `at`.
        pub fn note(&mut self, index: u32, at: At) {
            if self.largest.is_none_or(|(largest, _)| index > largest) {
                self.largest = Some((index, at));
            }
        }

        /// Fails, through `error`, when the largest stored index shifted down by `base`
        /// is not below `vertices`. The message shows the index as written in the file:
        /// the stored value plus `shown_offset`.
        pub fn check(
            &self,
            vertices: usize,
            base: u32,
            shown_offset: u32,
            error: impl FnOnce(At, String) -> Error,
        ) -> Result<()> {
            match self.largest {
                Some((largest, at)) if largest.saturating_sub(base) as usize >= vertices => {
                    let shown = u64::from(largest) + u64::from(shown_offset);
                    Err(error(
                        at,
                        format!("face index {shown} out of range (file has {vertices} vertices)"),
                    ))
                }
                _ => Ok(()),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fan_keeps_winding() {
        let mut triangles = Vec::new();
        fan_triangulate(&[0, 1, 2, 3, 4], &mut triangles);
        assert_eq!(triangles, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    }

    #[test]
    fn rows_strip_comments_and_crlf() {
        let rows: Vec<_> = text::rows(b"# c\r\n\r\nv 1 2 3 # tail\r\n  \n")
            .map(|row| (row.line, row.content.to_vec()))
            .collect();
        assert_eq!(rows, vec![(3, b"v 1 2 3".to_vec())]);
    }

    #[test]
    fn last_line_counts_unterminated_lines() {
        assert_eq!(text::last_line(b"a\nb"), 2);
        assert_eq!(text::last_line(b"a\nb\n"), 2);
        assert_eq!(text::last_line(b""), 1);
    }

    #[test]
    fn coordinates_reject_non_finite_and_accept_fortran() {
        assert_eq!(text::coordinate(b"1.5D+02"), Ok(150.0));
        assert!(text::coordinate(b"nan")
            .unwrap_err()
            .contains("not a finite"));
        assert!(text::coordinate(b"inf").is_err());
        assert!(text::coordinate(b"x1").unwrap_err().contains("'x1'"));
    }

    #[test]
    fn negative_index_before_first_vertex_fails() {
        let err = parse(Path::new("t.obj"), b"v 0 0 0\nf -1 -2 -3\n").unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
    }
}
