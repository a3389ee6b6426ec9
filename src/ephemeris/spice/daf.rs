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
    // Records past the file's end all land on its last slot: bound the walk by the file,
    // not by FWARD, which a crafted file sets near 2³¹.
    (2..(fward as usize).min(records + 1)).for_each(|r| kind[r] = Kind::Text);
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
        let doubles = count
            .checked_mul(summary_size)
            .and_then(|n| n.checked_add(3));
        if doubles.is_none_or(|n| n > RECORD / 8) {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A big-endian DAF of `records` records with the given file record.
    fn big_endian(records: usize, nd: i32, ni: i32, fward: i32) -> Vec<u8> {
        let mut bytes = vec![0u8; records * RECORD];
        bytes[8..12].copy_from_slice(&nd.to_be_bytes());
        bytes[12..16].copy_from_slice(&ni.to_be_bytes());
        bytes[76..80].copy_from_slice(&fward.to_be_bytes());
        bytes[88..96].copy_from_slice(b"BIG-IEEE");
        bytes
    }

    /// A summary record whose count saturates the integer conversion (1e300) is refused:
    /// the size arithmetic used to wrap and the byte swap to index past the record.
    #[test]
    fn a_saturated_summary_count_is_an_error() {
        let mut bytes = big_endian(3, 2, 6, 2);
        bytes[RECORD + 16..RECORD + 24].copy_from_slice(&1e300f64.to_be_bytes());
        let e = to_little_endian(Path::new("k.bsp"), &bytes).unwrap_err();
        assert!(e.to_string().contains("more summaries than fit"), "{e}");
    }

    /// A forward pointer near 2³¹ is a broken chain, found without walking two billion
    /// records.
    #[test]
    fn a_huge_forward_pointer_is_an_error() {
        let bytes = big_endian(2, 2, 6, i32::MAX);
        let e = to_little_endian(Path::new("k.bsp"), &bytes).unwrap_err();
        assert!(e.to_string().contains("broken summary record chain"), "{e}");
    }
}
