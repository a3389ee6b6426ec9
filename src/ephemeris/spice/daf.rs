//! DAF byte order: big-endian SPK and PCK files made native (little-endian) for anise.
//!
//! In: the bytes of a DAF (NAIF Double precision Array File). Out: the same file with
//! every number in little-endian order, following the DAF Required Reading's layout:
//! record 1 is the file record (integers ND, NI, FWARD, BWARD, FREE and the format word
//! "BIG-IEEE"/"LTL-IEEE"), records 2 … FWARD−1 hold comment text, a chain of summary
//! records (three doubles, then NSUM summaries of ND doubles and NI integers) each
//! followed by a name record (text) starts at FWARD, and every other record holds doubles.

use crate::error::{Error, Result};
use std::path::Path;

const RECORD: usize = 1024;

/// `bytes` with little-endian numbers (unchanged if already little-endian).
pub fn to_little_endian(path: &Path, bytes: &[u8]) -> Result<Vec<u8>> {
    let format = bytes.get(88..96).unwrap_or_default();
    if format != b"BIG-IEEE" {
        return Ok(bytes.to_vec());
    }
    let bad = |msg: &str| Error::file(path, format!("big-endian DAF: {msg}"));
    if bytes.len() < RECORD || bytes.len() % RECORD != 0 {
        return Err(bad("its size is not a whole number of 1024-byte records"));
    }
    let mut out = bytes.to_vec();
    let int_at = |at: usize| i32::from_be_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let (nd, ni, fward) = (int_at(8), int_at(12), int_at(76));
    if !(0..=124).contains(&nd) || !(2..=250).contains(&ni) || fward < 2 {
        return Err(bad("implausible file record (ND, NI or FWARD)"));
    }
    for at in [8, 12, 76, 80, 84] {
        out[at..at + 4].reverse();
    }
    out[88..96].copy_from_slice(b"LTL-IEEE");
    let records = bytes.len() / RECORD;
    let mut kind = vec![Kind::Doubles; records + 1];
    kind[1] = Kind::Done;
    (2..fward as usize).for_each(|r| kind[r.min(records)] = Kind::Text);
    let summary_size = nd as usize + (ni as usize).div_ceil(2);
    let mut next = fward as usize;
    while next != 0 {
        if next > records || kind[next] == Kind::Done {
            return Err(bad("broken summary record chain"));
        }
        let at = (next - 1) * RECORD;
        let double = |k: usize| {
            f64::from_be_bytes(
                bytes[at + 8 * k..at + 8 * k + 8]
                    .try_into()
                    .expect("8 bytes"),
            )
        };
        let (following, count) = (double(0) as usize, double(2) as usize);
        if 3 + count * summary_size > RECORD / 8 {
            return Err(bad("a summary record claims more summaries than fit"));
        }
        swap_summary_record(
            &mut out[at..at + RECORD],
            nd as usize,
            ni as usize,
            count,
            summary_size,
        );
        kind[next] = Kind::Done;
        if next < records {
            kind[next + 1] = Kind::Text;
        }
        next = following;
    }
    for (r, k) in kind.iter().enumerate().skip(1) {
        if *k == Kind::Doubles {
            out[(r - 1) * RECORD..r * RECORD]
                .chunks_exact_mut(8)
                .for_each(<[u8]>::reverse);
        }
    }
    Ok(out)
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Doubles,
    Text,
    Done,
}

fn swap_summary_record(record: &mut [u8], nd: usize, ni: usize, count: usize, size: usize) {
    record[..24].chunks_exact_mut(8).for_each(<[u8]>::reverse);
    for s in 0..count {
        let start = 24 + 8 * size * s;
        record[start..start + 8 * nd]
            .chunks_exact_mut(8)
            .for_each(<[u8]>::reverse);
        let ints = start + 8 * nd;
        record[ints..ints + 4 * ni]
            .chunks_exact_mut(4)
            .for_each(<[u8]>::reverse);
    }
}
