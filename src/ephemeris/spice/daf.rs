//! DAF checks and byte order: SPK and PCK files checked where anise trusts them, and
//! big-endian ones made native (little-endian) for anise.
//!
//! In: the bytes of a DAF (NAIF Double precision Array File). Out: the same file with
//! every number in little-endian order, following the DAF Required Reading's layout:
//! record 1 is the file record (integers ND, NI, FWARD, BWARD, FREE and the format word
//! "BIG-IEEE"/"LTL-IEEE"), records 2 … FWARD−1 hold comment text, a chain of summary
//! records (three doubles, then NSUM summaries of ND doubles and NI integers) each
//! followed by a name record (text) starts at FWARD, and every other record holds doubles.
//!
//! Before anything is handed to anise, in either byte order: the format word, ND, NI and
//! FWARD must be plausible; the summary chain must stay inside the file, visit no record
//! twice, and hold no more summaries than a record fits; and the segments anise evaluates
//! must hold finite numbers of plausible size and a record count within their length.
//! anise multiplies pointers and counts by record sizes unchecked (an overflow, a panic
//! where overflow checks are on), panics on a position whose norm overflows, and echoes
//! a bad format word's raw bytes in its error.

use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;

const RECORD: usize = 1024;

/// Largest magnitude of a number in a segment anise evaluates: real kernels stay below
/// 1e20 (km, km/s, s, rad); beyond 1e154 the square of a coordinate overflows.
const MAX_MAGNITUDE: f64 = 1e100;

/// How far a Chebyshev record's midpoint may lie from the centre of its interval, as a
/// share of half the interval: none in real kernels (DE421, MAR085, the Moon's PCK), a
/// little for rounding. At 1e-7, even a polynomial of degree 10⁵ stays finite.
const MIDPOINT_SLACK: f64 = 1e-7;

/// `bytes`, checked, with little-endian numbers (unchanged if already little-endian).
pub fn to_little_endian(path: &Path, bytes: &[u8]) -> Result<Vec<u8>> {
    let bad = |msg: &str| Error::file(path, format!("DAF: {msg}"));
    let big = match bytes.get(88..96) {
        Some(b"BIG-IEEE") => true,
        Some(b"LTL-IEEE") => false,
        _ => return Err(bad("no format word (BIG-IEEE or LTL-IEEE) at byte 88")),
    };
    let daf = Daf { bytes, big };
    let layout = daf.layout().map_err(bad)?;
    let chain = daf.summary_chain(&layout).map_err(bad)?;
    if has_loop(&daf.centres(&layout, &chain)) {
        return Err(bad(
            "its segments' centres form a loop (a body is its own centre)",
        ));
    }
    if big {
        Ok(daf.swapped(&layout, &chain))
    } else {
        Ok(bytes.to_vec())
    }
}

/// The file being read and its byte order.
struct Daf<'a> {
    bytes: &'a [u8],
    big: bool,
}

/// The file record's numbers slim relies on.
struct Layout {
    nd: usize,
    ni: usize,
    /// The first summary record (1-based).
    fward: usize,
    /// Whole records in the file.
    records: usize,
    /// An SPK or a binary PCK: anise reads every summary slot of its summary records,
    /// whatever their count says.
    anise_reads: bool,
}

impl Layout {
    /// Doubles one summary takes.
    fn summary_size(&self) -> usize {
        self.nd + self.ni.div_ceil(2)
    }

    /// The summaries of a summary record that counts `count`: those anise reads.
    fn summaries(&self, count: usize) -> usize {
        if self.anise_reads {
            (RECORD / 8 - 3) / self.summary_size()
        } else {
            count
        }
    }
}

/// One summary record of the chain: its number (1-based) and the summaries read from it.
struct SummaryRecord {
    record: usize,
    summaries: usize,
}

impl Daf<'_> {
    /// The `N` bytes at `at`, little-endian.
    fn word<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut word: [u8; N] = self.bytes[at..at + N].try_into().expect("N bytes");
        if self.big {
            word.reverse();
        }
        word
    }

    fn int(&self, at: usize) -> i32 {
        i32::from_le_bytes(self.word(at))
    }

    fn double(&self, at: usize) -> f64 {
        f64::from_le_bytes(self.word(at))
    }

    fn layout(&self) -> std::result::Result<Layout, &'static str> {
        let size = self.bytes.len();
        if size < RECORD || (self.big && !size.is_multiple_of(RECORD)) {
            return Err("its size is not a whole number of 1024-byte records");
        }
        let (nd, ni, fward) = (self.int(8), self.int(12), self.int(76));
        if !(0..=124).contains(&nd) || !(2..=250).contains(&ni) || fward < 2 {
            return Err("implausible file record (ND, NI or FWARD)");
        }
        // anise reads the summaries of a "DAF/SPK" as 2 doubles and 6 integers, and of a
        // "DAF/PCK" as 2 and 5, whatever ND and NI say.
        let fixed = match self.bytes[..8].trim_ascii_end() {
            b"DAF/SPK" => Some((2, 6)),
            b"DAF/PCK" => Some((2, 5)),
            _ => None,
        };
        if fixed.is_some_and(|fixed| fixed != (nd, ni)) {
            return Err("ND and NI are not 2 and 6 (SPK) or 2 and 5 (binary PCK)");
        }
        Ok(Layout {
            nd: nd as usize,
            ni: ni as usize,
            fward: fward as usize,
            records: size / RECORD,
            anise_reads: fixed.is_some(),
        })
    }

    /// The summary records from FWARD on. The walk is bounded by the file, not by the
    /// pointers, which a crafted file sets near 2³¹ or to a loop.
    fn summary_chain(
        &self,
        layout: &Layout,
    ) -> std::result::Result<Vec<SummaryRecord>, &'static str> {
        let mut visited = vec![false; layout.records + 1];
        visited[1] = true; // the file record
        let mut chain = Vec::new();
        let mut next = layout.fward;
        while next != 0 {
            if next > layout.records || visited[next] {
                return Err("broken summary record chain");
            }
            visited[next] = true;
            let at = (next - 1) * RECORD;
            let count = whole(self.double(at + 16))
                .filter(|&n| 3 + n * layout.summary_size() <= RECORD / 8)
                .ok_or("a summary record claims more summaries than fit")?;
            let summaries = layout.summaries(count);
            for s in 0..summaries {
                self.check_summary(layout, at + 24 + 8 * layout.summary_size() * s)?;
            }
            chain.push(SummaryRecord {
                record: next,
                summaries,
            });
            next = whole(self.double(at)).ok_or("broken summary record chain")?;
        }
        Ok(chain)
    }

    /// The summary at byte `at` of an SPK or binary PCK. Its centre (SPK) or reference
    /// frame (PCK) must not be −2³¹, which anise takes the absolute value of (an
    /// overflow). Its segment, if of a type anise evaluates (SPK types 1, 2, 3, 8, 9, 12
    /// and 13, binary PCK type 2), must hold only numbers within ±[`MAX_MAGNITUDE`] and
    /// must not count more records (its last number) than it has numbers: anise
    /// multiplies the count by the record length unchecked (type 9 overflowed on a count
    /// of 1e300), and a coefficient of 3e284 km made a position whose norm is ∞, whose
    /// light time hifitime refused with a panic.
    fn check_summary(&self, layout: &Layout, at: usize) -> std::result::Result<(), &'static str> {
        if !layout.anise_reads {
            return Ok(());
        }
        let ints = at + 8 * layout.nd;
        let int = |k: usize| self.int(ints + 4 * k);
        if int(1) == i32::MIN {
            return Err("a summary's centre or frame is -2147483648");
        }
        let spk = layout.ni == 6;
        let evaluated = if spk {
            [1, 2, 3, 8, 9, 12, 13].contains(&int(3))
        } else {
            int(2) == 2
        };
        let (begin, end) = (int(layout.ni - 2), int(layout.ni - 1));
        let (Ok(begin), Ok(end)) = (usize::try_from(begin), usize::try_from(end)) else {
            return Ok(()); // anise refuses addresses outside the file itself
        };
        if !evaluated || begin < 1 || end < begin || 8 * end > self.bytes.len() {
            return Ok(());
        }
        let number = |address: usize| self.double(8 * (address - 1));
        if !(begin..=end).all(|a| number(a).abs() <= MAX_MAGNITUDE) {
            return Err("a segment holds a number beyond ±1e100 (or not a number)");
        }
        if whole(number(end)).is_none_or(|count| count > end - begin + 1) {
            return Err("a segment's record count is not a whole number within its length");
        }
        let chebyshev = !spk || [2, 3].contains(&int(3));
        if chebyshev && end >= begin + 3 {
            let span = [self.double(at), self.double(at + 8)];
            return self.check_chebyshev(span, begin, end);
        }
        Ok(())
    }

    /// A Chebyshev segment (SPK types 2 and 3, binary PCK type 2) whose `span` is that of
    /// its summary. anise evaluates record k's polynomials at (t − MID_k)/(INTLEN/2) for t
    /// in the k-th interval of INTLEN from INIT (the last record for any t beyond), so the
    /// records must sit on their intervals and cover the span, keeping that argument
    /// within ±1: an INTLEN of 7e-310 made it huge, the position infinite, and hifitime
    /// panicked on the infinite light time.
    fn check_chebyshev(
        &self,
        span: [f64; 2],
        begin: usize,
        end: usize,
    ) -> std::result::Result<(), &'static str> {
        let number = |address: usize| self.double(8 * (address - 1));
        let (init, interval) = (number(end - 3), number(end - 2));
        // As anise reads them: RSIZE cut to a whole number, N whole (checked before).
        let (size, records) = (number(end - 1) as usize, number(end) as usize);
        if size < 2 || records.saturating_mul(size).saturating_add(4) > end - begin + 1 {
            return Ok(()); // anise refuses these itself
        }
        let slack = MIDPOINT_SLACK * interval / 2.0;
        let near = |x: f64, y: f64| (x - y).abs() <= slack; // false for NaN
        let centred = (0..records).all(|k| {
            let centre = init + (k as f64 + 0.5) * interval;
            near(number(begin + k * size), centre)
        });
        let last = init + records as f64 * interval;
        let covered = span[0] >= init - slack && span[1] <= last + slack;
        if interval > 0.0 && centred && covered {
            Ok(())
        } else {
            Err("a Chebyshev segment's records do not sit on the intervals that cover it")
        }
    }

    /// An SPK's links from each segment's target to its centre (none for other files).
    fn centres(&self, layout: &Layout, chain: &[SummaryRecord]) -> BTreeMap<i32, Vec<i32>> {
        let mut centres: BTreeMap<i32, Vec<i32>> = BTreeMap::new();
        if !layout.anise_reads || layout.ni != 6 {
            return centres;
        }
        let size = 8 * layout.summary_size();
        for summary in chain {
            let first = (summary.record - 1) * RECORD + 24;
            for at in (0..summary.summaries).map(|s| first + s * size) {
                if self.bytes[at..at + size].iter().any(|&b| b != 0) {
                    let ints = at + 8 * layout.nd;
                    let (target, centre) = (self.int(ints), self.int(ints + 4));
                    centres.entry(target).or_default().push(centre);
                }
            }
        }
        centres
    }

    /// The file with every number little-endian: integers of the file record, the
    /// summaries, and every record of doubles (not the comment and name records).
    fn swapped(&self, layout: &Layout, chain: &[SummaryRecord]) -> Vec<u8> {
        let mut out = self.bytes.to_vec();
        for at in [8, 12, 76, 80, 84] {
            out[at..at + 4].reverse();
        }
        out[88..96].copy_from_slice(b"LTL-IEEE");
        let mut kind = vec![Kind::Doubles; layout.records + 1];
        kind[1] = Kind::Done;
        (2..layout.fward.min(layout.records + 1)).for_each(|r| kind[r] = Kind::Text);
        for summary in chain {
            let at = (summary.record - 1) * RECORD;
            swap_summary_record(&mut out[at..at + RECORD], layout, summary.summaries);
            kind[summary.record] = Kind::Done;
            if summary.record < layout.records && kind[summary.record + 1] != Kind::Done {
                kind[summary.record + 1] = Kind::Text;
            }
        }
        for (r, k) in kind.iter().enumerate().skip(1) {
            if *k == Kind::Doubles {
                out[(r - 1) * RECORD..r * RECORD]
                    .chunks_exact_mut(8)
                    .for_each(<[u8]>::reverse);
            }
        }
        out
    }
}

/// Whether following centres from some body leads back to it. anise walks from each body
/// through its centres to a common root in a path of fixed depth; a loop (a segment of
/// garbage whose target is its own centre) made it index past that path (a panic).
fn has_loop(centres: &BTreeMap<i32, Vec<i32>>) -> bool {
    #[derive(PartialEq)]
    enum Visit {
        OnPath,
        Explored,
    }
    let mut seen: BTreeMap<i32, Visit> = BTreeMap::new();
    for &start in centres.keys() {
        if seen.contains_key(&start) {
            continue;
        }
        seen.insert(start, Visit::OnPath);
        // The bodies from `start` on, each with the index of its next centre to follow.
        let mut path = vec![(start, 0)];
        while let Some(&(body, next)) = path.last() {
            let Some(&centre) = centres.get(&body).and_then(|c| c.get(next)) else {
                seen.insert(body, Visit::Explored);
                path.pop();
                continue;
            };
            path.last_mut().expect("a body on the path").1 += 1;
            match seen.get(&centre) {
                Some(Visit::OnPath) => return true,
                Some(Visit::Explored) => {}
                None => {
                    seen.insert(centre, Visit::OnPath);
                    path.push((centre, 0));
                }
            }
        }
    }
    false
}

/// A record pointer or count stored as a double: a whole number, not absurdly large.
fn whole(x: f64) -> Option<usize> {
    (x.fract() == 0.0 && (0.0..=f64::from(i32::MAX)).contains(&x)).then_some(x as usize)
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Kind {
    Doubles,
    Text,
    Done,
}

fn swap_summary_record(record: &mut [u8], layout: &Layout, count: usize) {
    let (nd, ni, size) = (layout.nd, layout.ni, layout.summary_size());
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

    /// Little-endian files are checked too: anise multiplied a summary record's next
    /// pointer (here 1e300, saturated to 2⁶⁴ − 1) by the record size, and overflowed.
    #[test]
    fn a_little_endian_chain_leaving_the_file_is_an_error() {
        let mut bytes = vec![0u8; 3 * RECORD];
        bytes[8..12].copy_from_slice(&2i32.to_le_bytes());
        bytes[12..16].copy_from_slice(&6i32.to_le_bytes());
        bytes[76..80].copy_from_slice(&2i32.to_le_bytes());
        bytes[88..96].copy_from_slice(b"LTL-IEEE");
        bytes[RECORD..RECORD + 8].copy_from_slice(&1e300f64.to_le_bytes());
        let e = to_little_endian(Path::new("k.bsp"), &bytes).unwrap_err();
        assert!(e.to_string().contains("broken summary record chain"), "{e}");
        bytes[RECORD..RECORD + 8].copy_from_slice(&0f64.to_le_bytes());
        assert!(to_little_endian(Path::new("k.bsp"), &bytes).is_ok());
    }

    /// A little-endian SPK of 4 records with one segment of `segment_type` holding
    /// `data` from double 385 (record 4) on, its summary counted `nsum` in the summary
    /// record and spanning 0 s.
    fn little_endian_spk(nsum: f64, segment_type: i32, data: &[f64]) -> Vec<u8> {
        let mut bytes = vec![0u8; 4 * RECORD];
        bytes[..8].copy_from_slice(b"DAF/SPK ");
        for (at, int) in [(8, 2), (12, 6), (76, 2)] {
            bytes[at..at + 4].copy_from_slice(&i32::to_le_bytes(int));
        }
        bytes[88..96].copy_from_slice(b"LTL-IEEE");
        bytes[RECORD + 16..RECORD + 24].copy_from_slice(&nsum.to_le_bytes());
        let last = 384 + data.len() as i32;
        // Target, centre, frame, type, first and last address.
        for (k, int) in [2000433, 10, 1, segment_type, 385, last]
            .into_iter()
            .enumerate()
        {
            let at = RECORD + 40 + 4 * k;
            bytes[at..at + 4].copy_from_slice(&i32::to_le_bytes(int));
        }
        for (k, x) in data.iter().enumerate() {
            let at = 3 * RECORD + 8 * k;
            bytes[at..at + 8].copy_from_slice(&x.to_le_bytes());
        }
        bytes
    }

    /// A type-9 segment of one state: 6 numbers, its epoch, the degree, the count.
    const TYPE_9: [f64; 8] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];

    /// A type-9 segment whose state count (its last double) exceeds its length is refused
    /// (anise computed six doubles per state from it and overflowed), and so is one with a
    /// number anise's arithmetic overflows on, and a centre of −2³¹; also when the
    /// summary record counts no summaries (anise reads every slot).
    #[test]
    fn a_segment_anise_would_overflow_on_is_an_error() {
        let read = |bytes: &[u8]| to_little_endian(Path::new("k.bsp"), bytes);
        for nsum in [1.0, 0.0] {
            let valid = little_endian_spk(nsum, 9, &TYPE_9);
            assert!(read(&valid).is_ok());
            let mut bytes = valid.clone();
            bytes[3 * RECORD + 56..3 * RECORD + 64].copy_from_slice(&1e9f64.to_le_bytes());
            let e = read(&bytes).unwrap_err();
            assert!(e.to_string().contains("record count"), "{e}");
            // A coefficient whose square overflows (the position's norm, its light time).
            let mut bytes = valid.clone();
            bytes[3 * RECORD..3 * RECORD + 8].copy_from_slice(&3e284f64.to_le_bytes());
            let e = read(&bytes).unwrap_err();
            assert!(e.to_string().contains("beyond ±1e100"), "{e}");
            let mut bytes = valid;
            bytes[RECORD + 44..RECORD + 48].copy_from_slice(&i32::MIN.to_le_bytes());
            let e = read(&bytes).unwrap_err();
            assert!(e.to_string().contains("-2147483648"), "{e}");
        }
    }

    /// anise reads an SPK's summaries as 2 doubles and 6 integers whatever ND and NI say.
    #[test]
    fn an_spk_with_another_summary_layout_is_an_error() {
        let mut bytes = little_endian_spk(1.0, 9, &TYPE_9);
        bytes[8..12].copy_from_slice(&0i32.to_le_bytes());
        let e = to_little_endian(Path::new("k.bsp"), &bytes).unwrap_err();
        assert!(e.to_string().contains("ND and NI"), "{e}");
    }

    /// A type-2 record must sit on its interval: anise evaluates it at (t − MID)/(INTLEN/2),
    /// and an INTLEN of 7e-310 made that, and the position, infinite.
    #[test]
    fn a_chebyshev_record_off_its_interval_is_an_error() {
        // One record of degree 0 over [−1, 1] s: MID, RADIUS, x, y, z; INIT, INTLEN,
        // RSIZE, N.
        let record = |interval: f64, mid: f64| {
            little_endian_spk(1.0, 2, &[mid, 1.0, 7.0, 8.0, 9.0, -1.0, interval, 5.0, 1.0])
        };
        let read = |bytes: &[u8]| to_little_endian(Path::new("k.bsp"), bytes);
        assert!(read(&record(2.0, 0.0)).is_ok());
        for (interval, mid) in [(7e-310, 0.0), (2.0, 0.5), (0.0, 0.0), (-2.0, 0.0)] {
            let e = read(&record(interval, mid)).unwrap_err();
            assert!(e.to_string().contains("Chebyshev"), "{interval} {mid}: {e}");
        }
    }

    /// Centre links that lead back to a body are refused; a tree is not.
    #[test]
    fn a_loop_of_centres_is_found() {
        let links = |pairs: &[(i32, i32)]| {
            let mut centres: BTreeMap<i32, Vec<i32>> = BTreeMap::new();
            for &(target, centre) in pairs {
                centres.entry(target).or_default().push(centre);
            }
            centres
        };
        assert!(!has_loop(&links(&[
            (301, 3),
            (399, 3),
            (3, 0),
            (10, 0),
            (401, 4),
            (4, 0)
        ])));
        assert!(has_loop(&links(&[(7, 7)])));
        assert!(has_loop(&links(&[(401, 4), (4, 499), (499, 4), (10, 0)])));
    }

    /// A damaged format word is named, not echoed (anise quoted its raw bytes).
    #[test]
    fn a_damaged_format_word_is_an_error() {
        let mut bytes = big_endian(2, 2, 6, 2);
        bytes[88..96].copy_from_slice(b"\0\0LTL-IE");
        let e = to_little_endian(Path::new("k.bsp"), &bytes).unwrap_err();
        assert!(e
            .to_string()
            .ends_with("DAF: no format word (BIG-IEEE or LTL-IEEE) at byte 88"));
    }
}
