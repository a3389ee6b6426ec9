//! FITS images (NASA/IAU FITS Standard 4.0): the primary HDU of a file.
//!
//! Written: BITPIX = −32 (IEEE float32, big-endian), NAXIS = 2, the image's header cards
//! (geometry of a rendered image: camera, Sun, epoch, band, unit), 2880-byte blocks.
//! Rows are stored bottom row first, so that FITS viewers, which put the first row at the
//! bottom, show the picture upright. Read: BITPIX 8, 16, 32, −32 or −64 with BSCALE/BZERO,
//! NAXIS = 2 (or 3 with NAXIS3 = 1), rows restored to top-first; header cards become the
//! image's header (COMMENT, HISTORY and structural keywords excluded).

use super::{Card, Image, Value};
use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use std::path::Path;

const BLOCK: usize = 2880;
const CARD: usize = 80;
/// Keywords that describe the data layout, written and read by this module itself.
const STRUCTURAL: [&str; 10] = [
    "SIMPLE", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2", "NAXIS3", "EXTEND", "BSCALE", "BZERO", "END",
];

/// Writes `image` as a float32 FITS file.
pub fn write(path: &Path, image: &Image) -> Result<()> {
    let mut cards = vec![
        card("SIMPLE", &Value::Logical(true), "conforms to FITS standard"),
        card("BITPIX", &Value::Integer(-32), "IEEE single precision"),
        card("NAXIS", &Value::Integer(2), ""),
        card("NAXIS1", &Value::Integer(image.width as i64), "columns"),
        card(
            "NAXIS2",
            &Value::Integer(image.height as i64),
            "rows (bottom row first)",
        ),
    ];
    for c in &image.header {
        if !STRUCTURAL.contains(&c.key.as_str()) {
            cards.push(card(&c.key, &c.value, &c.comment));
        }
    }
    cards.push(format!("{:<80}", "END"));
    let mut bytes: Vec<u8> = cards.concat().into_bytes();
    pad(&mut bytes, b' ');
    for row in image.pixels.chunks(image.width.max(1)).rev() {
        for &x in row {
            bytes.extend_from_slice(&(x as f32).to_be_bytes());
        }
    }
    pad(&mut bytes, 0);
    write_atomic(path, &bytes)
}

fn pad(bytes: &mut Vec<u8>, fill: u8) {
    let rem = bytes.len() % BLOCK;
    if rem != 0 {
        bytes.resize(bytes.len() + BLOCK - rem, fill);
    }
}

/// One 80-character header card.
fn card(key: &str, value: &Value, comment: &str) -> String {
    let value = match value {
        Value::Logical(b) => format!("{:>20}", if *b { "T" } else { "F" }),
        Value::Integer(i) => format!("{i:>20}"),
        Value::Number(x) if x.is_finite() => format!("{x:>20.12E}"),
        Value::Number(_) => format!("{:<20}", "'NaN'"),
        // A card holds at most 68 characters between the quotes.
        Value::Text(s) => {
            let mut quoted = s.replace('\'', "''");
            while quoted.len() > 68 {
                quoted.pop();
                if quoted.ends_with('\'') && !quoted.ends_with("''") {
                    quoted.pop();
                }
            }
            format!("{:<20}", format!("'{quoted:<8}'"))
        }
    };
    let ascii = |s: &str| -> String { s.chars().filter(|c| (' '..='~').contains(c)).collect() };
    let mut line = format!("{:<8}= {}", ascii(key), ascii(&value));
    if !comment.is_empty() {
        line.push_str(" / ");
        line.push_str(&ascii(comment));
    }
    line.truncate(CARD);
    format!("{line:<80}")
}

/// Reads the primary image of a FITS file.
pub fn read(path: &Path) -> Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let (cards, data_start) = header(path, &bytes)?;
    let int = |key: &str| -> Result<i64> {
        match cards.iter().find(|c| c.key == key).map(|c| &c.value) {
            Some(Value::Integer(i)) => Ok(*i),
            _ => Err(Error::file(path, format!("missing or non-integer {key}"))),
        }
    };
    let number = |key: &str, default: f64| match cards.iter().find(|c| c.key == key) {
        Some(Card {
            value: Value::Number(x),
            ..
        }) => *x,
        Some(Card {
            value: Value::Integer(i),
            ..
        }) => *i as f64,
        _ => default,
    };
    let bitpix = int("BITPIX")?;
    let naxis = int("NAXIS")?;
    let extra_axes_are_one = (3..=naxis).all(|k| int(&format!("NAXIS{k}")).ok() == Some(1));
    if naxis < 2 || !extra_axes_are_one {
        return Err(Error::file(
            path,
            format!("the primary HDU holds no 2-D image (NAXIS = {naxis})"),
        ));
    }
    let (width, height) = (int("NAXIS1")?, int("NAXIS2")?);
    // Checked: NAXIS1 = NAXIS2 = 2³² overflowed the product (a panic with overflow
    // checks, and without them a wrapped 0 that passed as an empty image of 2³² × 2³²).
    let too_many = |n: i64| n > 1 << 28;
    if width <= 0 || height <= 0 || width.checked_mul(height).is_none_or(too_many) {
        return Err(Error::file(
            path,
            format!("implausible size {width} × {height}"),
        ));
    }
    let (width, height) = (width as usize, height as usize);
    let size = match bitpix {
        8 => 1,
        16 => 2,
        32 | -32 => 4,
        -64 => 8,
        other => return Err(Error::file(path, format!("unsupported BITPIX {other}"))),
    };
    let n = width * height;
    let data = bytes
        .get(data_start..data_start + n * size)
        .ok_or_else(|| {
            Error::at_byte(
                path,
                bytes.len() as u64,
                "data shorter than NAXIS1 × NAXIS2",
            )
        })?;
    let (scale, zero) = (number("BSCALE", 1.0), number("BZERO", 0.0));
    let raw = data.chunks_exact(size).map(|b| match bitpix {
        8 => b[0] as f64,
        16 => i16::from_be_bytes([b[0], b[1]]) as f64,
        32 => i32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
        -32 => f32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_be_bytes(b.try_into().expect("8-byte chunk")),
    });
    let stored: Vec<f64> = raw.map(|x| zero + scale * x).collect();
    let pixels = stored.chunks(width).rev().flatten().copied().collect();
    let header = cards
        .into_iter()
        .filter(|c| !STRUCTURAL.contains(&c.key.as_str()) && !c.key.starts_with("NAXIS"))
        .collect();
    Ok(Image {
        width,
        height,
        pixels,
        header,
    })
}

/// The header cards and the offset of the data.
fn header(path: &Path, bytes: &[u8]) -> Result<(Vec<Card>, usize)> {
    if !bytes.starts_with(b"SIMPLE  =") {
        return Err(Error::file(
            path,
            "not a FITS file (it does not start with SIMPLE)",
        ));
    }
    let mut cards = Vec::new();
    for (k, raw) in bytes.chunks(CARD).enumerate() {
        let offset = (k * CARD) as u64;
        let text = std::str::from_utf8(raw)
            .map_err(|_| Error::at_byte(path, offset, "header card is not ASCII"))?;
        let key = text.get(..8).unwrap_or(text).trim_end().to_string();
        if key == "END" {
            let end = (k + 1) * CARD;
            return Ok((cards, end.div_ceil(BLOCK) * BLOCK));
        }
        if text.get(8..10) != Some("= ") {
            continue; // COMMENT, HISTORY, blank cards
        }
        let (value, comment) = split_value(&text[10..]);
        let value = parse_value(value.trim()).ok_or_else(|| {
            let key = crate::error::printable(&key, 8);
            Error::at_byte(path, offset, format!("cannot read the value of {key}"))
        })?;
        cards.push(Card {
            key,
            value,
            comment: comment.trim().to_string(),
        });
    }
    Err(Error::file(path, "header has no END card"))
}

/// Splits a card's value field from its comment (a '/' outside a quoted string).
fn split_value(field: &str) -> (&str, &str) {
    let mut quoted = false;
    for (i, c) in field.char_indices() {
        match c {
            '\'' => quoted = !quoted,
            '/' if !quoted => return (&field[..i], &field[i + 1..]),
            _ => {}
        }
    }
    (field, "")
}

fn parse_value(v: &str) -> Option<Value> {
    if let Some(s) = v.strip_prefix('\'') {
        let inner = s.strip_suffix('\'')?;
        return Some(Value::Text(inner.replace("''", "'").trim_end().to_string()));
    }
    match v {
        "T" => return Some(Value::Logical(true)),
        "F" => return Some(Value::Logical(false)),
        "" => return Some(Value::Text(String::new())),
        _ => {}
    }
    if let Ok(i) = v.parse::<i64>() {
        return Some(Value::Integer(i));
    }
    v.replace('D', "E").parse::<f64>().ok().map(Value::Number)
}
