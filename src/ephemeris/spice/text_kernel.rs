//! Text kernels (SPICE "KPL" files: text PCKs, frame kernels): the assignments inside their
//! `\begindata` … `\begintext` blocks.
//!
//! In: a file's text. Out: a map from variable name to its values (numbers or strings), in
//! order, with `+=` appending. Numbers may use Fortran `D` exponents. Errors name the file
//! and line. Only what slim reads is interpreted; other variables are kept but unused.

use crate::error::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

/// One value of a kernel variable.
#[derive(Debug, Clone, PartialEq)]
pub enum KernelValue {
    Number(f64),
    Text(String),
}

/// The variables of one or more text kernels.
#[derive(Debug, Clone, Default)]
pub struct TextKernel {
    vars: HashMap<String, Vec<KernelValue>>,
}

/// A parenthesised list still being read, possibly over several lines.
struct OpenList {
    name: String,
    append: bool,
    values: Vec<KernelValue>,
    start_line: usize,
}

impl TextKernel {
    /// Parses the data blocks of `text` (read from `path`) into this pool.
    pub fn parse_into(&mut self, path: &Path, text: &str) -> Result<()> {
        let mut in_data = false;
        let mut open: Option<OpenList> = None;
        for (n, raw) in text.lines().enumerate() {
            let (line, line_no) = (raw.trim(), n + 1);
            if line == "\\begindata" {
                in_data = true;
            } else if line == "\\begintext" {
                if let Some(list) = &open {
                    return Err(unclosed(path, list));
                }
                in_data = false;
            } else if in_data && !line.is_empty() {
                open = match open.take() {
                    Some(list) => self.feed(path, line_no, list, line)?,
                    None => self.assignment(path, line_no, line)?,
                };
            }
        }
        match open {
            Some(list) => Err(unclosed(path, &list)),
            None => Ok(()),
        }
    }

    /// Reads `NAME = value`, `NAME += value` or the start of `NAME = ( …`.
    fn assignment(&mut self, path: &Path, line_no: usize, line: &str) -> Result<Option<OpenList>> {
        let (name, append, value) = split_assignment(path, line_no, line)?;
        match value.strip_prefix('(') {
            Some(inner) => {
                let list = OpenList {
                    name,
                    append,
                    values: Vec::new(),
                    start_line: line_no,
                };
                self.feed(path, line_no, list, inner)
            }
            None => {
                let values = parse_values(path, line_no, value)?;
                self.store(name, append, values);
                Ok(None)
            }
        }
    }

    /// Adds `text` to an open list; stores the list if `text` closes it.
    fn feed(
        &mut self,
        path: &Path,
        line_no: usize,
        mut list: OpenList,
        text: &str,
    ) -> Result<Option<OpenList>> {
        let (inside, closed) = match text.find(')') {
            Some(end) => (&text[..end], true),
            None => (text, false),
        };
        list.values.extend(parse_values(path, line_no, inside)?);
        if !closed {
            return Ok(Some(list));
        }
        self.store(list.name, list.append, list.values);
        Ok(None)
    }

    fn store(&mut self, name: String, append: bool, values: Vec<KernelValue>) {
        let slot = self.vars.entry(name).or_default();
        if !append {
            slot.clear();
        }
        slot.extend(values);
    }

    /// The numbers of variable `name`, if it exists and holds only numbers.
    pub fn numbers(&self, name: &str) -> Option<Vec<f64>> {
        self.vars
            .get(name)?
            .iter()
            .map(|v| match v {
                KernelValue::Number(x) => Some(*x),
                KernelValue::Text(_) => None,
            })
            .collect()
    }

    /// The first string of variable `name`.
    pub fn text(&self, name: &str) -> Option<&str> {
        self.vars.get(name)?.iter().find_map(|v| match v {
            KernelValue::Text(s) => Some(s.as_str()),
            KernelValue::Number(_) => None,
        })
    }

    /// The strings of variable `name`, if it exists and holds only strings.
    pub fn texts(&self, name: &str) -> Option<Vec<&str>> {
        self.vars
            .get(name)?
            .iter()
            .map(|v| match v {
                KernelValue::Text(s) => Some(s.as_str()),
                KernelValue::Number(_) => None,
            })
            .collect()
    }

    /// The variable names.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.vars.keys().map(String::as_str)
    }
}

fn unclosed(path: &Path, list: &OpenList) -> Error {
    Error::at_line(
        path,
        list.start_line,
        format!("'{}': list not closed by ')'", shown(&list.name)),
    )
}

fn split_assignment<'a>(
    path: &Path,
    line_no: usize,
    line: &'a str,
) -> Result<(String, bool, &'a str)> {
    let (name, append, value) = if let Some((n, v)) = line.split_once("+=") {
        (n, true, v)
    } else if let Some((n, v)) = line.split_once('=') {
        (n, false, v)
    } else {
        return Err(Error::at_line(
            path,
            line_no,
            format!("expected NAME = value, found '{}'", shown(line)),
        ));
    };
    let name = name.trim();
    if name.is_empty() || name.contains(char::is_whitespace) {
        return Err(Error::at_line(
            path,
            line_no,
            format!("not a variable name: '{}'", shown(name)),
        ));
    }
    Ok((name.to_string(), append, value.trim()))
}

/// Values separated by blanks or commas: numbers, 'quoted strings' or @dates (kept as text).
fn parse_values(path: &Path, line_no: usize, text: &str) -> Result<Vec<KernelValue>> {
    let mut values = Vec::new();
    let mut rest = text.trim_start_matches(|c: char| c.is_whitespace() || c == ',');
    while !rest.is_empty() {
        if let Some(quoted) = rest.strip_prefix('\'') {
            let end = quoted
                .find('\'')
                .ok_or_else(|| Error::at_line(path, line_no, "string not closed by '"))?;
            values.push(KernelValue::Text(quoted[..end].to_string()));
            rest = &quoted[end + 1..];
        } else {
            let end = rest
                .find(|c: char| c.is_whitespace() || c == ',')
                .unwrap_or(rest.len());
            let token = &rest[..end];
            values.push(if let Some(date) = token.strip_prefix('@') {
                KernelValue::Text(date.to_string())
            } else {
                KernelValue::Number(parse_number(token).ok_or_else(|| {
                    Error::at_line(path, line_no, format!("not a number: '{}'", shown(token)))
                })?)
            });
            rest = &rest[end..];
        }
        rest = rest.trim_start_matches(|c: char| c.is_whitespace() || c == ',');
    }
    Ok(values)
}

/// Kernel text as an error message quotes it: control characters escaped (a damaged
/// file's NUL or escape sequence must not reach a terminal) and at most 80 characters (a
/// message names what is wrong, it does not echo the file).
fn shown(text: &str) -> String {
    crate::error::printable(text, 80)
}

fn parse_number(token: &str) -> Option<f64> {
    let x: f64 = token.replace(['D', 'd'], "E").parse().ok()?;
    x.is_finite().then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_lists_appends_strings_and_fortran_numbers() {
        let text = "junk = 1\n\\begindata\nBODY401_PM = ( 176.625 1128.84475928\n 12.72192797D-8 )\nBODY4_NUT_PREC_ANGLES = ( 1 2 )\nBODY4_NUT_PREC_ANGLES += ( 3, 4 )\nFRAME_X_NAME = 'MOON_ME'\n\\begintext\nnot = data\n";
        let mut k = TextKernel::default();
        k.parse_into(Path::new("t.tpc"), text).unwrap();
        assert_eq!(
            k.numbers("BODY401_PM").unwrap(),
            vec![176.625, 1128.84475928, 12.72192797e-8]
        );
        assert_eq!(
            k.numbers("BODY4_NUT_PREC_ANGLES").unwrap(),
            vec![1.0, 2.0, 3.0, 4.0]
        );
        assert_eq!(k.text("FRAME_X_NAME"), Some("MOON_ME"));
        assert!(k.numbers("junk").is_none() && k.numbers("not").is_none());
    }

    #[test]
    fn errors_name_the_line() {
        let mut k = TextKernel::default();
        let e = k
            .parse_into(Path::new("t.tpc"), "\\begindata\nA = 1\nB = ( 1 x )\n")
            .unwrap_err();
        assert!(e.to_string().contains("t.tpc: line 3"), "{e}");
        let e = k
            .parse_into(Path::new("t.tpc"), "\\begindata\nA = ( 1 2\n")
            .unwrap_err();
        assert!(e.to_string().contains("line 2"), "{e}");
    }
}
