//! Surrounding terrain for a terrain patch, from a GMT grid: the heights of a netCDF-3
//! (classic) GMT grid as a triangulated OBJ, with the patch's footprint cut out.
//!
//! ```text
//! cargo run --release --example dem_surroundings -- IN.grd OUT.obj X0 X1 Y0 Y1
//! ```
//! In: a GMT grid with 1-D `x`, `y` and 2-D `z[y][x]` (float or double; NaN cells are
//! left out), all in one length unit, and the patch's footprint `X0..X1 × Y0..Y1` in that
//! unit. Out: an OBJ of two triangles per grid cell, counter-clockwise seen from +z (so
//! normals point up), without the cells that reach into the footprint (the patch itself
//! stands there; a coarse cell overlapping it would shade it falsely). This is how
//! `data/shapes/moon/haworth-surroundings.obj` was made from python-flux's `tmp256.grd`
//! (see `data/SOURCES.md`).

use std::fmt::Write as _;

type Error = Box<dyn std::error::Error>;

fn main() -> Result<(), Error> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [input, output, x0, x1, y0, y1] = &args[..] else {
        return Err("usage: dem_surroundings IN.grd OUT.obj X0 X1 Y0 Y1".into());
    };
    let footprint = [x0.parse()?, x1.parse()?, y0.parse()?, y1.parse()?];
    let bytes = std::fs::read(input).map_err(|e| format!("{input}: {e}"))?;
    let grid = Grid::read(&bytes).map_err(|e| format!("{input}: {e}"))?;
    let obj = grid.obj_without(footprint);
    let tmp = format!("{output}.tmp");
    std::fs::write(&tmp, obj).map_err(|e| format!("{tmp}: {e}"))?;
    std::fs::rename(&tmp, output).map_err(|e| format!("{output}: {e}"))?;
    Ok(())
}

/// Heights `z[row][col]` at nodes `(x[col], y[row])`.
struct Grid {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl Grid {
    /// Parses the netCDF classic header (dimensions, attributes, variables) and reads
    /// the variables `x`, `y` and `z`.
    fn read(bytes: &[u8]) -> Result<Grid, String> {
        let mut r = Reader { bytes, at: 0 };
        if r.take(4)? != b"CDF\x01" {
            return Err("not a netCDF classic (CDF1) file".into());
        }
        r.u32()?; // record count
        let dims: Vec<usize> = r.list(0x0A, |r| {
            r.name()?;
            Ok(r.u32()? as usize)
        })?;
        r.attributes()?;
        let vars = r.list(0x0B, |r| {
            let name = r.name()?;
            let count = r.u32()? as usize;
            let shape: Vec<usize> = (0..count)
                .map(|_| {
                    let id = r.u32()? as usize;
                    dims.get(id)
                        .copied()
                        .ok_or(format!("bad dimension id {id}"))
                })
                .collect::<Result<_, _>>()?;
            r.attributes()?;
            let kind = r.u32()?;
            r.u32()?; // size
            let begin = r.u32()? as usize;
            Ok((name, shape, kind, begin))
        })?;
        let values = |wanted: &str| -> Result<Vec<f64>, String> {
            let (_, shape, kind, begin) = vars
                .iter()
                .find(|v| v.0 == wanted)
                .ok_or(format!("no variable '{wanted}'"))?;
            let count: usize = shape.iter().product();
            let width = match kind {
                5 => 4,
                6 => 8,
                _ => return Err(format!("'{wanted}' is neither float nor double")),
            };
            let data = bytes
                .get(*begin..begin + count * width)
                .ok_or(format!("'{wanted}' runs past the end of the file"))?;
            Ok(data
                .chunks_exact(width)
                .map(|c| match width {
                    4 => f32::from_be_bytes(c.try_into().unwrap()) as f64,
                    _ => f64::from_be_bytes(c.try_into().unwrap()),
                })
                .collect())
        };
        let grid = Grid {
            x: values("x")?,
            y: values("y")?,
            z: values("z")?,
        };
        if grid.z.len() != grid.x.len() * grid.y.len() {
            return Err("z is not x by y".into());
        }
        Ok(grid)
    }

    /// The grid as OBJ text without the cells that reach into `[x0, x1, y0, y1]`.
    fn obj_without(&self, [x0, x1, y0, y1]: [f64; 4]) -> String {
        let (nx, ny) = (self.x.len(), self.y.len());
        let mut text =
            String::from("# surrounding terrain: a GMT grid's cells outside a patch footprint\n");
        for row in 0..ny {
            for col in 0..nx {
                let z = self.z[row * nx + col];
                let _ = writeln!(text, "v {} {} {}", self.x[col], self.y[row], z);
            }
        }
        let node = |row: usize, col: usize| row * nx + col + 1;
        for row in 0..ny - 1 {
            for col in 0..nx - 1 {
                let (xa, xb) = (
                    self.x[col].min(self.x[col + 1]),
                    self.x[col].max(self.x[col + 1]),
                );
                let (ya, yb) = (
                    self.y[row].min(self.y[row + 1]),
                    self.y[row].max(self.y[row + 1]),
                );
                let overlaps = xa < x1 && xb > x0 && ya < y1 && yb > y0;
                let corners = [
                    (row, col),
                    (row, col + 1),
                    (row + 1, col + 1),
                    (row + 1, col),
                ];
                let missing = corners.iter().any(|&(r, c)| self.z[r * nx + c].is_nan());
                if overlaps || missing {
                    continue;
                }
                // Counter-clockwise seen from +z when x and y both increase.
                let [a, b, c, d] = corners.map(|(r, c)| node(r, c));
                let flip = (self.x[1] < self.x[0]) != (self.y[1] < self.y[0]);
                if flip {
                    let _ = writeln!(text, "f {a} {c} {b}\nf {a} {d} {c}");
                } else {
                    let _ = writeln!(text, "f {a} {b} {c}\nf {a} {c} {d}");
                }
            }
        }
        text
    }
}

/// Big-endian reads through a byte slice, with netCDF's 4-byte padding.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at + n;
        let slice = self.bytes.get(self.at..end).ok_or("truncated header")?;
        self.at = end;
        Ok(slice)
    }

    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_be_bytes(self.take(4)?.try_into().unwrap()))
    }

    fn padded(&mut self, n: usize) -> Result<&'a [u8], String> {
        let slice = self.take(n)?;
        self.take((4 - n % 4) % 4)?;
        Ok(slice)
    }

    fn name(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        Ok(String::from_utf8_lossy(self.padded(n)?).into_owned())
    }

    /// A tagged list (or the absent list, two zero words).
    fn list<T>(
        &mut self,
        tag: u32,
        mut item: impl FnMut(&mut Self) -> Result<T, String>,
    ) -> Result<Vec<T>, String> {
        let found = self.u32()?;
        let count = self.u32()? as usize;
        if found != tag && !(found == 0 && count == 0) {
            return Err(format!("expected list tag {tag:#x}, found {found:#x}"));
        }
        (0..count).map(|_| item(self)).collect()
    }

    /// Skips an attribute list.
    fn attributes(&mut self) -> Result<(), String> {
        self.list(0x0C, |r| {
            r.name()?;
            let width = match r.u32()? {
                1 | 2 => 1,
                3 => 2,
                4 | 5 => 4,
                6 => 8,
                k => return Err(format!("unknown attribute type {k}")),
            };
            let count = r.u32()? as usize;
            r.padded(count * width)?;
            Ok(())
        })?;
        Ok(())
    }
}
