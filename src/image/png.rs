//! PNG images: 8- or 16-bit grey with a linear stretch stated in the file.
//!
//! Written: value x maps to the digital number DN = round((x − lo)/(hi − lo) · DNmax),
//! clipped to 0 … DNmax (255 or 65535). The stretch and the unit are stored in tEXt
//! chunks (`slim:stretch` = "linear LO HI", `slim:unit`), so a reader can undo it:
//! x = lo + DN/DNmax · (hi − lo), exact to half a DN step. Read: any PNG (palette, grey,
//! RGB, with or without alpha; colour becomes the mean of R, G, B; alpha is ignored); with
//! a `slim:stretch` chunk the values are returned in physical units, otherwise as DN/DNmax.

use super::{Image, Value};
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use std::path::Path;

/// How values map to digital numbers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stretch {
    /// Value shown black.
    pub lo: f64,
    /// Value shown white.
    pub hi: f64,
}

impl Stretch {
    /// From 0 to the image's largest value (1 when that is not positive).
    pub fn zero_to_max(image: &Image) -> Stretch {
        let max = image.max();
        Stretch {
            lo: 0.0,
            hi: if max > 0.0 { max } else { 1.0 },
        }
    }
}

const STRETCH_KEY: &str = "slim:stretch";
const UNIT_KEY: &str = "slim:unit";

/// Writes `image` as a grey PNG of `bits` (8 or 16) per pixel with `stretch`.
pub fn write(path: &Path, image: &Image, bits: u8, stretch: Stretch) -> Result<()> {
    let err = |e: &dyn std::fmt::Display| Error::output(path, e);
    if stretch.hi <= stretch.lo || !stretch.lo.is_finite() || !stretch.hi.is_finite() {
        return Err(err(&format!(
            "stretch {} … {} is not an increasing finite range",
            stretch.lo, stretch.hi
        )));
    }
    let (depth, dn_max) = match bits {
        8 => (::png::BitDepth::Eight, 255.0),
        16 => (::png::BitDepth::Sixteen, 65535.0),
        _ => return Err(err(&format!("PNG depth must be 8 or 16 bits, not {bits}"))),
    };
    let dn = |x: f64| {
        let t = (x - stretch.lo) / (stretch.hi - stretch.lo);
        (if t.is_finite() { t } else { 0.0 }).clamp(0.0, 1.0) * dn_max
    };
    let data: Vec<u8> = if bits == 8 {
        image.pixels.iter().map(|&x| dn(x).round() as u8).collect()
    } else {
        image
            .pixels
            .iter()
            .flat_map(|&x| (dn(x).round() as u16).to_be_bytes())
            .collect()
    };
    let mut bytes = Vec::new();
    {
        let mut encoder = ::png::Encoder::new(&mut bytes, image.width as u32, image.height as u32);
        encoder.set_color(::png::ColorType::Grayscale);
        encoder.set_depth(depth);
        let unit = match image.get("BUNIT") {
            Some(Value::Text(u)) => u.clone(),
            _ => String::new(),
        };
        let text = format!("linear {:e} {:e}", stretch.lo, stretch.hi);
        encoder
            .add_text_chunk(STRETCH_KEY.into(), text)
            .map_err(|e| err(&e))?;
        encoder
            .add_text_chunk(UNIT_KEY.into(), unit)
            .map_err(|e| err(&e))?;
        let mut writer = encoder.write_header().map_err(|e| err(&e))?;
        writer.write_image_data(&data).map_err(|e| err(&e))?;
        writer.finish().map_err(|e| err(&e))?;
    }
    write_atomic(path, &bytes)
}

/// Reads a PNG; values in physical units when it states a `slim:stretch`.
pub fn read(path: &Path) -> Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |e: &dyn std::fmt::Display| Error::file(path, format!("not a readable PNG: {e}"));
    let mut decoder = ::png::Decoder::new(std::io::Cursor::new(&bytes));
    decoder.set_transformations(::png::Transformations::EXPAND);
    let mut reader = decoder.read_info().map_err(|e| bad(&e))?;
    check_palette(reader.info()).map_err(|e| bad(&e))?;
    let size = decoded_size(&reader, bytes.len()).map_err(|e| bad(&e))?;
    let mut buf = vec![0; size];
    let info = reader.next_frame(&mut buf).map_err(|e| bad(&e))?;
    let texts = &reader.info().uncompressed_latin1_text;
    let find = |key: &str| {
        texts
            .iter()
            .find(|t| t.keyword == key)
            .map(|t| t.text.clone())
    };
    let stretch = find(STRETCH_KEY)
        .map(|s| parse_stretch(path, &s))
        .transpose()?;
    let channels = info.color_type.samples();
    let sixteen = info.bit_depth == ::png::BitDepth::Sixteen;
    let dn_max = if sixteen { 65535.0 } else { 255.0 };
    let sample = |row: &[u8], k: usize| -> f64 {
        if sixteen {
            u16::from_be_bytes([row[2 * k], row[2 * k + 1]]) as f64
        } else {
            row[k] as f64
        }
    };
    let (width, height) = (info.width as usize, info.height as usize);
    let colour = if channels >= 3 { 3 } else { 1 };
    let mut pixels = Vec::with_capacity(width * height);
    for row in buf[..info.buffer_size()].chunks(info.line_size) {
        for x in 0..width {
            let sum: f64 = (0..colour).map(|c| sample(row, x * channels + c)).sum();
            let t = sum / colour as f64 / dn_max;
            pixels.push(stretch.map_or(t, |s| s.lo + t * (s.hi - s.lo)));
        }
    }
    let mut image = Image {
        width,
        height,
        pixels,
        header: Vec::new(),
    };
    if let Some(unit) = find(UNIT_KEY).filter(|u| !u.is_empty()) {
        image.set("BUNIT", Value::Text(unit), "from the PNG's slim:unit");
    }
    Ok(image)
}

/// A palette (PLTE) must hold 1 to 256 whole RGB entries: the png crate (0.18) expands
/// indices through a palette of any length and indexed past one of 40 bytes (a panic).
fn check_palette(info: &::png::Info) -> std::result::Result<(), String> {
    match info.palette.as_deref() {
        Some(palette) if palette.len() % 3 != 0 || palette.len() > 3 * 256 => Err(format!(
            "its palette (PLTE) is {} bytes, not 1 to 256 entries of 3",
            palette.len()
        )),
        _ => Ok(()),
    }
}

/// Most pixels a PNG may have: 2²⁸, as for FITS (2 GiB of values).
const MAX_PIXELS: u64 = 1 << 28;

/// How much larger than its file a decoded image can be: deflate expands its input at
/// most 1032-fold, and the expansion to 8-bit samples at most 32-fold (a 1-bit palette
/// index becomes 4 bytes of RGBA).
const MAX_EXPANSION: usize = 1032 * 32;

/// The decoded image's size in bytes, refused before anything is allocated when the
/// header claims more pixels than [`MAX_PIXELS`] or more bytes than a file of
/// `file_bytes` can hold: a few bytes of header can claim 2³¹ × 2³¹ pixels, and the
/// buffer was allocated from that claim (16 GiB from a 74-byte file).
fn decoded_size<R: std::io::BufRead + std::io::Seek>(
    reader: &::png::Reader<R>,
    file_bytes: usize,
) -> std::result::Result<usize, String> {
    let (width, height) = reader.info().size();
    let pixels = u64::from(width) * u64::from(height);
    let size = reader.output_buffer_size();
    match size.filter(|&n| n <= MAX_EXPANSION.saturating_mul(file_bytes)) {
        Some(n) if pixels <= MAX_PIXELS => Ok(n),
        _ => Err(format!(
            "the header claims {width} × {height} pixels, more than a {file_bytes}-byte \
             file holds (or than the {MAX_PIXELS} read at most)"
        )),
    }
}

fn parse_stretch(path: &Path, text: &str) -> Result<Stretch> {
    // The chunk's text is quoted in errors: control characters escaped, shortened.
    let shown = crate::error::printable(text, 80);
    let parts: Vec<&str> = text.split_whitespace().collect();
    match parts.as_slice() {
        ["linear", lo, hi] => match (lo.parse(), hi.parse()) {
            (Ok(lo), Ok(hi)) => Ok(Stretch { lo, hi }),
            _ => Err(Error::file(path, format!("bad {STRETCH_KEY} '{shown}'"))),
        },
        _ => Err(Error::file(
            path,
            format!("unknown {STRETCH_KEY} '{shown}' (expected 'linear LO HI')"),
        )),
    }
}
