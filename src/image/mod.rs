//! Image: a 2-D grid of floating-point pixel values with a header, and its files.
//!
//! In/out: [`Image`] — `width × height` values in row-major order, row 0 at the top of the
//! picture (as a camera sees it), in the unit named by the header's `BUNIT` card
//! (W m⁻² sr⁻¹ for radiance, 1 for I/F). Files: FITS (float32 written; 8/16/32-bit
//! integer and 32/64-bit float read, see [`fits`]) and PNG (8- or 16-bit grey with a
//! linear stretch stated in the file, see [`png`]). Every file is written to a temporary
//! name and renamed when complete.

pub mod fits;
pub mod png;

use crate::error::{Error, Result};
use std::path::Path;

/// A header value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Text(String),
    Number(f64),
    Integer(i64),
    Logical(bool),
}

/// One header entry: keyword (≤ 8 characters, upper case), value and comment.
#[derive(Debug, Clone, PartialEq)]
pub struct Card {
    pub key: String,
    pub value: Value,
    pub comment: String,
}

/// A single-channel image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// Row-major, row 0 at the top.
    pub pixels: Vec<f64>,
    /// Metadata written to (and read from) the file header, in order.
    pub header: Vec<Card>,
}

impl Image {
    /// An image of zeros.
    pub fn new(width: usize, height: usize) -> Image {
        Image {
            width,
            height,
            pixels: vec![0.0; width * height],
            header: Vec::new(),
        }
    }

    /// The value at column `x`, row `y` (row 0 at the top).
    pub fn at(&self, x: usize, y: usize) -> f64 {
        self.pixels[y * self.width + x]
    }

    /// Adds or replaces a header card.
    pub fn set(&mut self, key: &str, value: Value, comment: &str) {
        let card = Card {
            key: key.to_ascii_uppercase(),
            value,
            comment: comment.to_string(),
        };
        match self.header.iter_mut().find(|c| c.key == card.key) {
            Some(c) => *c = card,
            None => self.header.push(card),
        }
    }

    /// The header value of `key`, if present.
    pub fn get(&self, key: &str) -> Option<&Value> {
        let key = key.to_ascii_uppercase();
        self.header.iter().find(|c| c.key == key).map(|c| &c.value)
    }

    /// A numeric header value (integers included).
    pub fn number(&self, key: &str) -> Option<f64> {
        match self.get(key)? {
            Value::Number(x) => Some(*x),
            Value::Integer(i) => Some(*i as f64),
            _ => None,
        }
    }

    /// A text header value.
    pub fn text(&self, key: &str) -> Option<&str> {
        match self.get(key)? {
            Value::Text(s) => Some(s),
            _ => None,
        }
    }

    /// Largest finite pixel value (0 for an empty or all-non-finite image).
    pub fn max(&self) -> f64 {
        self.pixels
            .iter()
            .copied()
            .filter(|x| x.is_finite())
            .fold(0.0, f64::max)
    }
}

/// Reads an image file by extension: `.fits`/`.fit`/`.fts` or `.png`.
pub fn read_image(path: &Path) -> Result<Image> {
    let ext = crate::lowercase_extension(path);
    match ext.as_str() {
        "fits" | "fit" | "fts" => fits::read(path),
        "png" => png::read(path),
        _ => Err(Error::file(
            path,
            "unknown image format: use the extension .fits (.fit, .fts) or .png",
        )),
    }
}
