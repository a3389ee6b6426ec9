//! Errors of every pipeline stage.
//!
//! Every variant carries the context a user needs to fix the input: the file and the
//! line (or byte offset) for file errors, the key path for scene errors, the body and the
//! epoch for geometry errors. The CLI prints the `Display` form as one line.

use std::path::{Path, PathBuf};

/// Result type of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// All errors the library reports.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file's content is malformed at a known place (`at` is e.g. "line 12" or "byte 84").
    #[error("{}: {at}: {msg}", path.display())]
    Parse {
        path: PathBuf,
        at: String,
        msg: String,
    },
    /// A file is well formed but unusable as a whole (empty mesh, unknown format, ...).
    #[error("{}: {msg}", path.display())]
    File { path: PathBuf, msg: String },
    /// A scene file is invalid; `key` is the dotted path of the offending key.
    #[error("{}: {key}: {msg}", path.display())]
    Scene {
        path: PathBuf,
        key: String,
        msg: String,
    },
    /// The geometry of a run is invalid (e.g. a body whose Sun direction is not finite).
    #[error("body '{body}', step {step}: {msg}")]
    Geometry {
        body: String,
        step: usize,
        msg: String,
    },
    /// A SPICE query failed: which body, in which frame, at which epoch, and why.
    #[error("SPICE: body '{body}' (NAIF {naif_id}), frame {frame}, epoch {epoch}: {msg}")]
    Spice {
        body: String,
        naif_id: i32,
        frame: String,
        epoch: String,
        msg: String,
    },
    /// Writing a result failed.
    #[error("{}: {msg}", path.display())]
    Output { path: PathBuf, msg: String },
    /// A command-line argument is invalid.
    #[error("{0}")]
    Usage(String),
    /// A run would need more memory than it may use: how much, for what, and the knob
    /// that shrinks it.
    #[error("{0}")]
    OverBudget(String),
    /// The run was stopped on request before it finished (a cancelled service job).
    #[error("the run was cancelled")]
    Cancelled,
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Error::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// A parse error at a line (1-based) of `path`.
    pub fn at_line(path: &Path, line: usize, msg: impl Into<String>) -> Self {
        Error::Parse {
            path: path.to_path_buf(),
            at: format!("line {line}"),
            msg: msg.into(),
        }
    }

    /// A parse error at a byte offset of a binary `path`.
    pub fn at_byte(path: &Path, offset: u64, msg: impl Into<String>) -> Self {
        Error::Parse {
            path: path.to_path_buf(),
            at: format!("byte {offset}"),
            msg: msg.into(),
        }
    }

    /// A whole-file error on `path`.
    pub fn file(path: &Path, msg: impl Into<String>) -> Self {
        Error::File {
            path: path.to_path_buf(),
            msg: msg.into(),
        }
    }

    /// A scene error at `key`. Key and message may quote the scene file (a misspelt key,
    /// a name, a flag), so both are made [`printable`]: at most 200 and 500 characters.
    pub fn scene(path: &Path, key: impl Into<String>, msg: impl Into<String>) -> Self {
        Error::Scene {
            path: path.to_path_buf(),
            key: printable(&key.into(), 200),
            msg: printable(&msg.into(), 500),
        }
    }

    /// An output error on `path`.
    pub fn output(path: &Path, msg: impl std::fmt::Display) -> Self {
        Error::Output {
            path: path.to_path_buf(),
            msg: msg.to_string(),
        }
    }
}

/// `text` as an error message may quote it: control characters (line breaks, terminal
/// escapes, NUL) written as escapes (`\n`, `\u{1b}`) and at most `max_chars` characters
/// as written, escapes included, the rest cut to `...`. For messages that quote a file's
/// content, which must stay one line that a terminal or a log shows as it is, however
/// broken the file.
pub fn printable(text: &str, max_chars: usize) -> String {
    let mut out = String::with_capacity(text.len().min(max_chars.saturating_mul(4)));
    let mut written = 0;
    for c in text.chars() {
        let escaped = c.is_control().then(|| c.escape_default());
        let width = escaped.clone().map_or(1, Iterator::count);
        if written + width > max_chars {
            out.push_str("...");
            break;
        }
        written += width;
        match escaped {
            Some(escaped) => out.extend(escaped),
            None => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::printable;

    #[test]
    fn printable_escapes_control_characters_and_shortens() {
        assert_eq!(printable("a\nb\u{1b}[31m\0", 40), "a\\nb\\u{1b}[31m\\u{0}");
        assert_eq!(printable("abcdef", 3), "abc...");
        assert_eq!(printable("abc", 3), "abc");
        // Escapes count as written: a NUL takes five characters.
        assert_eq!(printable("\0\0", 8), "\\u{0}...");
    }
}
