//! PDS plate-model text reader.
//!
//! In: the bytes of a whitespace-separated plate file in one of the layouts found in
//! the PDS Small Bodies Node archive and elsewhere:
//!
//! - tagged: `v x y z` and `f i j k` rows (also upper case `V`/`F`);
//! - counted: a first row `nv nf`, then `nv` vertex rows `x y z`, then `nf` plate rows
//!   `i j k`;
//! - classic: a row `nv`, `nv` rows `id x y z`, a row `nf`, `nf` rows `id i j k`.
//!
//! Vertex and plate rows of the counted and classic layouts may carry a leading id
//! column, which is ignored. `#` starts a comment; CRLF line ends are accepted.
//!
//! Out: a [`RawMesh`] with the vertices and plates in file order. Plate indices are
//! 1-based unless some plate uses index 0, in which case the whole file is 0-based.

use super::obj::text::{self, LargestIndex, Row};
use super::RawMesh;
use crate::error::{Error, Result};
use glam::DVec3;
use std::path::Path;

/// Parses a plate file of any supported layout.
pub(super) fn parse(path: &Path, bytes: &[u8]) -> Result<RawMesh> {
    let mut rows = text::rows(bytes).peekable();
    let first = rows
        .peek()
        .ok_or_else(|| Error::file(path, "the file holds no data rows"))?;
    let mut file = PlateFile {
        path,
        bytes,
        vertices: Vec::new(),
        plates: Plates::default(),
    };
    match first.fields::<3>() {
        ([tag, ..], _) if is_tag(tag) => file.read_tagged(rows)?,
        (_, 2) => file.read_counted(rows)?,
        (_, 1) => file.read_classic(rows)?,
        _ => {
            return Err(first.error(
                path,
                "unrecognised plate file layout: the first data row must be `v x y z`, \
                 `nv nf` (vertex and plate counts) or `nv` (vertex count)",
            ))
        }
    }
    let triangles = file.plates.into_zero_based(path, file.vertices.len())?;
    Ok(RawMesh {
        vertices: file.vertices,
        triangles,
    })
}

fn is_tag(token: &[u8]) -> bool {
    matches!(token, b"v" | b"V" | b"f" | b"F")
}

/// The file being read and what has been read from it so far.
struct PlateFile<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    vertices: Vec<DVec3>,
    plates: Plates,
}

impl PlateFile<'_> {
    /// `v x y z` / `f i j k` rows in any order.
    fn read_tagged<'r>(&mut self, rows: impl Iterator<Item = Row<'r>>) -> Result<()> {
        for row in rows {
            let (fields, count) = row.fields::<4>();
            let [tag, values @ ..] = fields;
            if count != 4 {
                return Err(row.error(
                    self.path,
                    format!(
                        "expected a tag and 3 values (`v x y z` or `f i j k`), found {count} \
                         values"
                    ),
                ));
            }
            match tag {
                b"v" | b"V" => self.vertices.push(vertex(self.path, &row, values)?),
                b"f" | b"F" => self.plates.push(self.path, &row, values)?,
                _ => {
                    return Err(row.error(
                        self.path,
                        format!("expected a 'v' or 'f' row, found {}", text::quoted(tag)),
                    ))
                }
            }
        }
        Ok(())
    }

    /// `nv nf`, then the vertex rows, then the plate rows.
    fn read_counted<'r>(&mut self, mut rows: impl Iterator<Item = Row<'r>>) -> Result<()> {
        let header = rows.next().ok_or_else(|| self.ends_early("the header"))?;
        let ([nv, nf], _) = header.fields::<2>();
        let vertex_count = count(self.path, &header, nv)?;
        let plate_count = count(self.path, &header, nf)?;
        self.read_vertex_rows(&mut rows, vertex_count)?;
        self.read_plate_rows(&mut rows, plate_count)?;
        self.expect_end(rows, plate_count)
    }

    /// `nv`, the vertex rows, `nf`, the plate rows.
    fn read_classic<'r>(&mut self, mut rows: impl Iterator<Item = Row<'r>>) -> Result<()> {
        let vertex_count = self.count_row(&mut rows, "the vertex count")?;
        self.read_vertex_rows(&mut rows, vertex_count)?;
        let plate_count = self.count_row(&mut rows, "the plate count")?;
        self.read_plate_rows(&mut rows, plate_count)?;
        self.expect_end(rows, plate_count)
    }

    /// A row holding a single count.
    fn count_row<'r>(&self, rows: &mut impl Iterator<Item = Row<'r>>, what: &str) -> Result<u64> {
        let row = rows.next().ok_or_else(|| self.ends_early(what))?;
        match row.fields::<1>() {
            ([value], 1) => count(self.path, &row, value),
            (_, found) => Err(row.error(
                self.path,
                format!("expected {what} alone on its row, found {found} values"),
            )),
        }
    }

    fn read_vertex_rows<'r>(
        &mut self,
        rows: &mut impl Iterator<Item = Row<'r>>,
        expected: u64,
    ) -> Result<()> {
        self.vertices.reserve(plausible_rows(expected, self.bytes));
        for read in 0..expected {
            let row = rows
                .next()
                .ok_or_else(|| self.ends_early(&format!("{read} of {expected} vertex rows")))?;
            let values = id_and_three_values(self.path, &row, "x y z")?;
            self.vertices.push(vertex(self.path, &row, values)?);
        }
        Ok(())
    }

    fn read_plate_rows<'r>(
        &mut self,
        rows: &mut impl Iterator<Item = Row<'r>>,
        expected: u64,
    ) -> Result<()> {
        self.plates
            .triangles
            .reserve(plausible_rows(expected, self.bytes));
        for read in 0..expected {
            let row = rows
                .next()
                .ok_or_else(|| self.ends_early(&format!("{read} of {expected} plate rows")))?;
            let values = id_and_three_values(self.path, &row, "i j k")?;
            self.plates.push(self.path, &row, values)?;
        }
        Ok(())
    }

    /// Rows after the last announced plate mean the counts are wrong.
    fn expect_end<'r>(&self, mut rows: impl Iterator<Item = Row<'r>>, plates: u64) -> Result<()> {
        match rows.next() {
            Some(row) => Err(row.error(
                self.path,
                format!("unexpected row after the {plates} plates announced by the header"),
            )),
            None => Ok(()),
        }
    }

    fn ends_early(&self, after: &str) -> Error {
        Error::at_line(
            self.path,
            text::last_line(self.bytes),
            format!("file ends after {after}"),
        )
    }
}

/// The three values of a vertex or plate row, skipping a leading id column.
fn id_and_three_values<'a>(path: &Path, row: &Row<'a>, names: &str) -> Result<[&'a [u8]; 3]> {
    match row.fields::<4>() {
        ([a, b, c, _], 3) => Ok([a, b, c]),
        ([_, a, b, c], 4) => Ok([a, b, c]),
        (_, found) => Err(row.error(
            path,
            format!("expected 3 values ({names}) or 4 (id {names}), found {found}"),
        )),
    }
}

fn vertex(path: &Path, row: &Row, values: [&[u8]; 3]) -> Result<DVec3> {
    let mut xyz = [0.0; 3];
    for (coordinate, token) in xyz.iter_mut().zip(values) {
        *coordinate = text::coordinate(token).map_err(|msg| row.error(path, msg))?;
    }
    Ok(DVec3::from_array(xyz))
}

fn count(path: &Path, row: &Row, token: &[u8]) -> Result<u64> {
    let value = text::integer(token).map_err(|msg| row.error(path, msg))?;
    u64::try_from(value)
        .map_err(|_| row.error(path, format!("a count cannot be negative, found {value}")))
}

/// How many rows of a header's announced count the file could actually hold, so that
/// a corrupt count cannot make us reserve memory the file does not back.
fn plausible_rows(announced: u64, bytes: &[u8]) -> usize {
    // The shortest possible row, "0 0 0\n", takes six bytes.
    const SHORTEST_ROW: usize = 6;
    let fitting = bytes.len() / SHORTEST_ROW;
    usize::try_from(announced).map_or(fitting, |n| n.min(fitting))
}

/// Plates as written (index base not yet known) and the index range they use.
#[derive(Default)]
struct Plates {
    triangles: Vec<[u32; 3]>,
    smallest: Option<u32>,
    largest: LargestIndex<usize>,
}

impl Plates {
    fn push(&mut self, path: &Path, row: &Row, values: [&[u8]; 3]) -> Result<()> {
        let mut triangle = [0; 3];
        for (index, token) in triangle.iter_mut().zip(values) {
            *index = plate_index(path, row, token)?;
            self.smallest = Some(self.smallest.map_or(*index, |s| s.min(*index)));
            self.largest.note(*index, row.line);
        }
        self.triangles.push(triangle);
        Ok(())
    }

    /// The plates as 0-based indices: the file is 0-based exactly when it uses index 0.
    fn into_zero_based(self, path: &Path, vertices: usize) -> Result<Vec<[u32; 3]>> {
        let base = match self.smallest {
            Some(0) | None => 0,
            Some(_) => 1,
        };
        self.largest.check(vertices, base, 0, |line, msg| {
            Error::at_line(path, line, msg)
        })?;
        let mut triangles = self.triangles;
        if base == 1 {
            // Every index is >= 1 here (the smallest is), so this cannot underflow.
            triangles
                .iter_mut()
                .for_each(|t| *t = t.map(|index| index - 1));
        }
        Ok(triangles)
    }
}

fn plate_index(path: &Path, row: &Row, token: &[u8]) -> Result<u32> {
    let value = text::integer(token).map_err(|msg| row.error(path, msg))?;
    u32::try_from(value).map_err(|_| {
        let why = if value < 0 {
            "vertex indices cannot be negative"
        } else {
            "it does not fit in 32 bits"
        };
        row.error(path, format!("invalid vertex index {value}: {why}"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<RawMesh> {
        parse(Path::new("t.tab"), text.as_bytes())
    }

    #[test]
    fn counted_layout_with_ids_and_one_based_indices() {
        let mesh = read("3 1\n1 0 0 0\n2 1 0 0\n3 0 1 0\n1 1 2 3\n").unwrap();
        assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
        assert_eq!(mesh.vertices[1], DVec3::X);
    }

    #[test]
    fn plausible_rows_is_bounded_by_file_size() {
        assert_eq!(plausible_rows(u64::MAX, &[0; 60]), 10);
        assert_eq!(plausible_rows(3, &[0; 60]), 3);
    }

    #[test]
    fn extra_rows_are_reported_at_their_line() {
        let err = read("3 1\n0 0 0\n1 0 0\n0 1 0\n1 2 3\n1 2 3\n").unwrap_err();
        assert!(err.to_string().contains("line 6"), "{err}");
    }
}
