//! Fuzzing every file reader and the service's request parsing with random and mutated
//! input (issue 15, "Systematic checks").
//!
//! For every case the property is: the reader returns (no panic); its peak allocation
//! while it runs stays below [`allocation_bound`]; and when it refuses the input, its error
//! is one line ([`check_message`]: no line break or other control character, at most
//! [`MAX_MESSAGE_CHARS`] characters) that names the file it read.
//!
//! Targets: OBJ, PLY, STL and PDS meshes, SPK and binary PCK kernels (loaded, then
//! evaluated), text kernels, TOML scenes, per-facet albedo files, FITS and PNG images
//! (feature `imaging`), and job and point-query request bodies (feature `serve`). Inputs:
//! the seeds in `tests/corpus/<target>/` (see its README), each first as it is, then cases
//! made from them by a seeded mutator (bit flips, bytes and keywords inserted, ranges
//! deleted or duplicated, splices from another seed, numbers replaced by extreme values,
//! binary words overwritten by extreme integers and floats, truncation) and some random
//! bytes. For a given corpus, case `i` of target `t` depends only on the base seed, `t`
//! and `i`.
//!
//! `cargo test --test fuzz` runs the default: every seed and [`DEFAULT_CASES`] cases per
//! target, 65,000 cases in about 7 s on two cores (test profile, opt-level 2). A long
//! campaign, about 15 minutes a process:
//!
//! ```sh
//! SLIM_FUZZ_CASES=1000000 cargo test --test fuzz -- --nocapture
//! ```
//!
//! Variables: `SLIM_FUZZ_CASES` (cases per target), `SLIM_FUZZ_SEED` (base seed, default
//! 0: run several processes with different seeds to use more cores), `SLIM_FUZZ_ONLY`
//! (comma-separated target names), `SLIM_FUZZ_REPLAY` (one case index: with the seed and
//! the target, it replays a failure; add `RUST_BACKTRACE=1` for a panic's backtrace),
//! `SLIM_FUZZ_PLAN=0` (accepted requests are not planned: by default their meshes and
//! ephemerides are built, as the service does before accepting a job). A failure names
//! the target, seed and case and leaves its input in `$TMPDIR/slim-fuzz-failures/`.
//! docs/accuracy.md says more.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------
// Allocation meter

#[global_allocator]
static METER: meter::Meter = meter::Meter;

/// A global allocator that counts the bytes live while a measurement runs and their peak.
/// The counters are global, not per thread, so that threads a reader starts (rayon while
/// planning a job) count too: cases run one at a time, in a single test.
mod meter {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::io::Write;
    use std::sync::atomic::{AtomicBool, AtomicIsize, Ordering::Relaxed};
    use std::sync::Mutex;

    /// While measuring, an allocation that would take the live total past this is
    /// refused, so that a runaway reader aborts the test (with the case's label on stderr)
    /// instead of exhausting the machine's memory.
    const HARD_CAP: isize = 4 << 30;

    static ARMED: AtomicBool = AtomicBool::new(false);
    static LIVE: AtomicIsize = AtomicIsize::new(0);
    static PEAK: AtomicIsize = AtomicIsize::new(0);
    /// What is being measured, printed if an allocation is refused.
    static LABEL: Mutex<String> = Mutex::new(String::new());

    pub struct Meter;

    /// Runs `f`, returning its result and the peak of bytes allocated and not yet freed
    /// while it ran. `label` is printed if `f` allocates past the hard cap.
    pub fn measure<R>(label: String, f: impl FnOnce() -> R) -> (R, usize) {
        *LABEL.lock().unwrap_or_else(|e| e.into_inner()) = label;
        LIVE.store(0, Relaxed);
        PEAK.store(0, Relaxed);
        ARMED.store(true, Relaxed);
        let result = f();
        ARMED.store(false, Relaxed);
        (result, PEAK.load(Relaxed).max(0) as usize)
    }

    /// Counts `bytes` more; false when they would pass the hard cap.
    fn admit(bytes: usize) -> bool {
        if !ARMED.load(Relaxed) {
            return true;
        }
        let bytes = bytes as isize; // a Layout's size never exceeds isize::MAX
        let live = LIVE.load(Relaxed);
        if bytes > HARD_CAP - live {
            refuse(bytes);
            return false;
        }
        let live = LIVE.fetch_add(bytes, Relaxed) + bytes;
        PEAK.fetch_max(live, Relaxed);
        true
    }

    fn release(bytes: usize) {
        if ARMED.load(Relaxed) {
            LIVE.fetch_sub(bytes as isize, Relaxed);
        }
    }

    /// Says which case ran away; writing to stderr allocates nothing.
    fn refuse(bytes: isize) {
        let mut err = std::io::stderr();
        let _ = writeln!(err, "fuzz: refused an allocation of {bytes} bytes");
        if let Ok(label) = LABEL.try_lock() {
            let _ = err.write_all(label.as_bytes());
            let _ = err.write_all(b"\n");
        }
    }

    // SAFETY: every call is forwarded unchanged to the system allocator; only a refusal
    // (a null pointer, which callers must handle) is added.
    unsafe impl GlobalAlloc for Meter {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            if !admit(layout.size()) {
                return std::ptr::null_mut();
            }
            unsafe { System.alloc(layout) }
        }

        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            if !admit(layout.size()) {
                return std::ptr::null_mut();
            }
            unsafe { System.alloc_zeroed(layout) }
        }

        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) };
            release(layout.size());
        }

        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            let old = layout.size();
            if new_size > old && !admit(new_size - old) {
                return std::ptr::null_mut();
            }
            let moved = unsafe { System.realloc(ptr, layout, new_size) };
            if new_size < old {
                release(old - new_size);
            }
            moved
        }
    }
}

/// The most a reader may hold at once: 64 bytes per input byte, and never less than
/// 64 MiB. A reader keeps the file's bytes (×1), a decoded copy (×3 at most: lossy UTF-8
/// turns one bad byte into three), and what it parsed: one f64 vertex (24 bytes) from as
/// little as 3 bytes of binary PLY (×8), a fan of 253 triangles (3036 bytes) from a
/// 256-byte polygon (×12), 8-byte pixels from 1-byte FITS pixels (×8, twice while rows
/// are reordered), each doubled while a vector grows. 64× covers these with room; the
/// floor covers fixed costs (an anise almanac, a planned scene's world and epochs).
fn allocation_bound(input_bytes: usize) -> usize {
    (64 << 20).max(64 * input_bytes)
}

/// Longest acceptable error message, in characters beyond the file's path: a line a
/// person reads, not an echo of the input.
const MAX_MESSAGE_CHARS: usize = 1000;

/// A case slower than this is a failure (a loop driven by a number in the input).
const SLOW_CASE: Duration = Duration::from_secs(10);

/// Mutated inputs are cut to this size.
const MAX_INPUT: usize = 64 << 10;

/// Cases per target after its seeds, unless `SLIM_FUZZ_CASES` says otherwise.
const DEFAULT_CASES: usize = 5000;

// ---------------------------------------------------------------------------------------
// Random numbers and mutations

/// SplitMix64: small, fast and good enough to drive mutations; seeded per case.
struct Rng(u64);

impl Rng {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (0 when n is 0).
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }

    /// True one time in `n`.
    fn one_in(&mut self, n: usize) -> bool {
        self.below(n) == 0
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// The generator of case `index` of `target` under `base`: cases are independent, so
/// any one can be replayed alone.
fn case_rng(base: u64, target: &str, index: usize) -> Rng {
    let name = target.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01B3)
    });
    let mut rng = Rng(base ^ name);
    rng.0 ^= rng.next_u64().wrapping_add(index as u64);
    rng
}

/// Numbers that break arithmetic, counts and conversions, as text.
const EXTREME_NUMBERS: &[&str] = &[
    "1e308",
    "-1e308",
    "1e-300",
    "-0",
    "0",
    "-1",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "2147483647",
    "-2147483648",
    "65535",
    "1e30",
    "1.5D+308",
    "0x10",
    "1_000",
    "99999999999999999999999999999",
    "0.5",
    "",
];

/// Bytes that change how text and binary formats are split and read.
const INTERESTING_BYTES: &[u8] = b"\0\xff\x7f\x80\n\r \t#-.09e()'\"=[]{}\\/\x1b\xc3\xef,@";

/// A binary word that breaks counts, sizes or floats: 4 or 8 bytes, in either byte order.
fn extreme_word(rng: &mut Rng) -> Vec<u8> {
    const INTS: &[u32] = &[
        0,
        1,
        2,
        255,
        1024,
        65535,
        0x4000_0000,
        0x7fff_ffff,
        0x8000_0000,
        0xffff_fffe,
        0xffff_ffff,
    ];
    const FLOATS: &[f64] = &[
        1e300,
        -1e300,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        -0.0,
        1e-300,
        2147483648.0,
        9.3e18,
        1e9,
    ];
    let mut word = match rng.below(3) {
        0 => rng.pick(INTS).to_le_bytes().to_vec(),
        1 => rng.pick(FLOATS).to_le_bytes().to_vec(),
        _ => (*rng.pick(FLOATS) as f32).to_le_bytes().to_vec(),
    };
    if rng.one_in(2) {
        word.reverse();
    }
    word
}

/// An offset to overwrite: anywhere, in a header's first words, or early in a 1024-byte
/// DAF record (where record pointers and summary counts live).
fn word_offset(rng: &mut Rng, len: usize) -> usize {
    match rng.below(3) {
        0 => rng.below(len),
        1 => 4 * rng.below(len.min(128) / 4 + 1),
        _ => 1024 * rng.below(len / 1024 + 1) + 8 * rng.below(8),
    }
}

/// What a case is made from: the seed it changes, a donor to splice from, and the
/// target's keywords.
struct Material<'a> {
    seed: &'a [u8],
    donor: &'a [u8],
    keywords: &'a [&'a str],
}

/// A new input: usually 1 to 4 mutations of the seed (up to 16 at times), now and then
/// random bytes.
fn make_input(rng: &mut Rng, material: &Material) -> Vec<u8> {
    if rng.one_in(32) {
        let len = rng.below(2048);
        return (0..len).map(|_| rng.next_u64() as u8).collect();
    }
    let mut data = material.seed.to_vec();
    let rounds = if rng.one_in(8) { 16 } else { 4 };
    for _ in 0..=rng.below(rounds) {
        mutate(rng, &mut data, material);
    }
    data.truncate(MAX_INPUT);
    data
}

fn mutate(rng: &mut Rng, data: &mut Vec<u8>, material: &Material) {
    match rng.below(11) {
        0 => flip_bit(rng, data),
        1 => set_interesting_byte(rng, data),
        2 => insert_keyword(rng, data, material.keywords),
        9 => overwrite_keyword(rng, data, material.keywords),
        3 => delete_range(rng, data),
        4 => duplicate_chunk(rng, data),
        5 => splice(rng, data, material.donor),
        6 | 7 => replace_number(rng, data),
        8 => overwrite_word(rng, data),
        _ => truncate(rng, data),
    }
}

fn flip_bit(rng: &mut Rng, data: &mut [u8]) {
    if !data.is_empty() {
        let at = rng.below(data.len());
        data[at] ^= 1 << rng.below(8);
    }
}

fn set_interesting_byte(rng: &mut Rng, data: &mut [u8]) {
    if !data.is_empty() {
        let at = rng.below(data.len());
        data[at] = *rng.pick(INTERESTING_BYTES);
    }
}

/// One of the target's keywords or an extreme number, between spaces, or a few random
/// bytes.
fn insert_keyword(rng: &mut Rng, data: &mut Vec<u8>, keywords: &[&str]) {
    let at = rng.below(data.len() + 1);
    let token: Vec<u8> = match rng.below(3) {
        0 if !keywords.is_empty() => rng.pick(keywords).as_bytes().to_vec(),
        1 => format!(" {} ", rng.pick(EXTREME_NUMBERS)).into_bytes(),
        _ => (0..=rng.below(16)).map(|_| rng.next_u64() as u8).collect(),
    };
    data.splice(at..at, token);
}

/// One of the target's keywords written over the input at a multiple of its own length,
/// so that an 80-character FITS card lands on a card.
fn overwrite_keyword(rng: &mut Rng, data: &mut Vec<u8>, keywords: &[&str]) {
    if keywords.is_empty() {
        return;
    }
    let keyword = rng.pick(keywords).as_bytes();
    let at = keyword.len() * rng.below(data.len() / keyword.len().max(1) + 1);
    overwrite(data, at, keyword);
}

/// `bytes` written over `data` from `at` on (at its end if `at` lies beyond), extending it
/// where they run past.
fn overwrite(data: &mut Vec<u8>, at: usize, bytes: &[u8]) {
    let at = at.min(data.len());
    let end = (at + bytes.len()).min(data.len());
    data.splice(at..end, bytes.iter().copied());
}

fn delete_range(rng: &mut Rng, data: &mut Vec<u8>) {
    let start = rng.below(data.len());
    let len = rng.below(64.min(data.len() - start) + 1);
    data.drain(start..start + len);
}

/// A chunk copied elsewhere, up to 64 times in a row (long lists, many elements).
fn duplicate_chunk(rng: &mut Rng, data: &mut Vec<u8>) {
    let start = rng.below(data.len());
    let len = rng.below(256.min(data.len() - start) + 1);
    let chunk = data[start..start + len].repeat(1 + rng.below(64) * usize::from(rng.one_in(4)));
    let at = rng.below(data.len() + 1);
    data.splice(at..at, chunk);
}

/// A chunk of the donor inserted, or written over the input.
fn splice(rng: &mut Rng, data: &mut Vec<u8>, donor: &[u8]) {
    let start = rng.below(donor.len());
    let chunk = &donor[start..start + rng.below(512.min(donor.len() - start) + 1)];
    let at = rng.below(data.len() + 1);
    if rng.one_in(2) {
        data.splice(at..at, chunk.iter().copied());
    } else {
        overwrite(data, at, chunk);
    }
}

/// The first number at or after a random place, replaced by an extreme one.
fn replace_number(rng: &mut Rng, data: &mut Vec<u8>) {
    let from = rng.below(data.len());
    let Some(digit) = data[from..].iter().position(u8::is_ascii_digit) else {
        return;
    };
    let is_number_byte = |b: &u8| b.is_ascii_alphanumeric() || b"+-.".contains(b);
    let mut start = from + digit;
    while start > 0 && is_number_byte(&data[start - 1]) {
        start -= 1;
    }
    let end = data[start..]
        .iter()
        .position(|b| !is_number_byte(b))
        .map_or(data.len(), |n| start + n);
    let extreme = rng.pick(EXTREME_NUMBERS).as_bytes();
    data.splice(start..end, extreme.iter().copied());
}

fn overwrite_word(rng: &mut Rng, data: &mut Vec<u8>) {
    let word = extreme_word(rng);
    let at = word_offset(rng, data.len());
    overwrite(data, at, &word);
}

fn truncate(rng: &mut Rng, data: &mut Vec<u8>) {
    let keep = rng.below(data.len() + 1);
    data.truncate(keep);
}

// ---------------------------------------------------------------------------------------
// Targets

/// What one call of a target gave: the reader's refusal (none: it accepted the input) and
/// the messages of queries on what it read.
struct Outcome {
    refusal: Option<String>,
    notes: Vec<String>,
}

impl Outcome {
    fn of<T, E: std::fmt::Display>(result: Result<T, E>) -> Outcome {
        Outcome {
            refusal: result.err().map(|e| e.to_string()),
            notes: Vec::new(),
        }
    }
}

/// A reader under test.
struct Target {
    /// Its name, and the folder of its seeds under `tests/corpus`.
    name: &'static str,
    read: fn(&Path) -> Outcome,
    /// Whether a refusal must name the file (request bodies have none).
    names_file: bool,
    /// Words worth inserting into its input.
    keywords: &'static [&'static str],
    /// A fix-up after mutation (checksums), applied to three cases in four.
    repair: Option<fn(&mut [u8])>,
}

fn target(
    name: &'static str,
    read: fn(&Path) -> Outcome,
    keywords: &'static [&'static str],
) -> Target {
    Target {
        name,
        read,
        names_file: true,
        keywords,
        repair: None,
    }
}

fn targets() -> Vec<Target> {
    #[allow(unused_mut)] // nothing is added without the imaging and serve features
    let mut list = vec![
        target(
            "obj",
            read_mesh,
            &["\nv 1 2 3\n", "\nf 1 2 3\n", "\nf -1 -2 -3 -4\n", "/", "//"],
        ),
        target("ply", read_mesh, PLY_KEYWORDS),
        target(
            "stl",
            read_mesh,
            &[
                "solid ",
                "\nfacet normal 0 0 1\n",
                "outer loop",
                "vertex 1 2 3\n",
                "endloop",
                "endfacet",
                "endsolid",
            ],
        ),
        target(
            "pds",
            read_mesh,
            &[
                "\nv 0 0 1\n",
                "\nf 1 2 3\n",
                "\n4294967295 1\n",
                "\n3\n",
                "#",
            ],
        ),
        target(
            "spk",
            load_kernel,
            &["DAF/SPK ", "BIG-IEEE", "LTL-IEEE", "NAIF/DAF"],
        ),
        target("bpc", load_kernel, &["DAF/PCK ", "BIG-IEEE", "LTL-IEEE"]),
        target("kernel", load_kernel, KERNEL_KEYWORDS),
        target("scene", read_scene, SCENE_KEYWORDS),
        target(
            "albedo",
            read_albedo,
            &["\n0.5\n", "\n# c\n", "\n1\n", "\u{feff}"],
        ),
    ];
    #[cfg(feature = "imaging")]
    list.extend(imaging::targets());
    #[cfg(feature = "serve")]
    list.extend(service::targets());
    list
}

const PLY_KEYWORDS: &[&str] = &[
    "\nelement vertex 4294967295\n",
    "\nelement face 18446744073709551615\n",
    "\nproperty list uint int vertex_indices\n",
    "\nproperty list uchar double vertex_index\n",
    "\nproperty float x\n",
    "\nformat binary_big_endian 1.0\n",
    "\nformat binary_little_endian 1.0\n",
    "\nformat ascii 1.0\n",
    "\nend_header\n",
    "\nelement edge 99999999\nproperty int v\n",
];

const KERNEL_KEYWORDS: &[&str] = &[
    "\n\\begindata\n",
    "\n\\begintext\n",
    "\nBODY4_MAX_PHASE_DEGREE = 1e30\n",
    "\nBODY2000433_NUT_PREC_RA = ( 1 2 3 )\n",
    "\nBODY4_NUT_PREC_ANGLES += ( 1 2 3 4 5 6 7 8 9 )\n",
    " += ",
    " = ( ",
    " ) ",
    "'",
    "@2000-JAN-01",
    "\nTKFRAME_31001_RELATIVE = 'MOON_ME'\n",
    "\nFRAME_1400433_CLASS = 3\n",
];

const SCENE_KEYWORDS: &[&str] = &[
    "\n[scatter]\n",
    "\n[[body]]\nname = \"x\"\nellipsoid = { levels = 12 }\n",
    "\n[camera]\nwidth = 4294967295\nheight = 2\nfov_deg = 1\n",
    "\nsteps_per_period = 1e9\n",
    "\nbin_width_w_m2 = 1e-300\n",
    "\nsolar_constant_w_m2 = 1e308\n",
    "\"\\u001b[31m\"",
    "\"a\\nb\"",
    "\n\"bad\\nkey\" = 1\n",
    "\nmode = \"\\u0000\"\n",
    "\nunits = \"k\\r\\nm\"\n",
    "\"../../../../etc/passwd\"",
    "\"/etc/hostname\"",
    "[[ephemeris.sun]]\n",
    " = ",
    "{ ",
    " }",
];

fn read_mesh(path: &Path) -> Outcome {
    Outcome::of(slim::mesh::read_mesh(path, None))
}

fn read_scene(path: &Path) -> Outcome {
    Outcome::of(slim::scene::Scene::load(path))
}

fn read_albedo(path: &Path) -> Outcome {
    Outcome::of(slim::scatter::albedo::read_albedo_file(path, 4))
}

/// Loads one kernel, then asks what a run asks of it: coverage and Sun vectors,
/// rotation models, radii and frames, each query's error kept as a note.
fn load_kernel(path: &Path) -> Outcome {
    match slim::ephemeris::spice::Kernels::load(&[path.to_path_buf()]) {
        Ok(kernels) => Outcome {
            refusal: None,
            notes: kernel_queries::ask(&kernels),
        },
        Err(e) => Outcome::of(Err::<(), _>(e)),
    }
}

mod kernel_queries {
    use anise::prelude::{Aberration, Frame};
    use hifitime::Epoch;
    use slim::ephemeris::spice::{Kernels, SpiceBody};

    /// Bodies asked about besides those the kernel names: the corpus's own.
    const BODIES: [i32; 5] = [2000433, 301, 401, 499, 10];
    /// Frames asked for, as scenes name them.
    const FRAMES: [&str; 5] = ["MOON_ME", "FUZZY_TILT", "IAU_FUZZY", "IAU_MARS", "J2000"];
    /// At most this many bodies of a kernel are asked about (a mutated kernel may name
    /// thousands).
    const MOST: usize = 8;

    pub fn ask(kernels: &Kernels) -> Vec<String> {
        let mut notes = Vec::new();
        ephemerides(kernels, &mut notes);
        orientations(kernels, &mut notes);
        for id in bodies(kernels) {
            rotation(kernels, id, &mut notes);
        }
        notes
    }

    fn bodies(kernels: &Kernels) -> Vec<i32> {
        let mut ids = kernels.bodies_with_rotation();
        ids.truncate(MOST);
        ids.extend(BODIES);
        ids
    }

    fn midpoint(start: Epoch, end: Epoch) -> Option<Epoch> {
        let mid = (start.to_tdb_seconds() + end.to_tdb_seconds()) / 2.0;
        mid.is_finite().then(|| Epoch::from_tdb_seconds(mid))
    }

    /// Every covered body seen from the Sun and from the solar-system barycentre.
    fn ephemerides(kernels: &Kernels, notes: &mut Vec<String>) {
        for (id, start, end) in kernels.ephemeris_coverage().into_iter().take(MOST) {
            let Some(epoch) = midpoint(start, end) else {
                continue;
            };
            for (observer, ab) in [(10, None), (0, Aberration::LT_S)] {
                if let Err(e) = kernels.vector_km(id, observer, epoch, ab) {
                    notes.push(e);
                }
            }
        }
    }

    /// Every binary-PCK frame's rotation from J2000, mid-coverage.
    fn orientations(kernels: &Kernels, notes: &mut Vec<String>) {
        let almanac = kernels.almanac();
        let Ok(domains) = almanac.bpc_domains() else {
            return;
        };
        for (id, (start, end)) in domains.into_iter().take(MOST) {
            let Some(epoch) = midpoint(start, end) else {
                continue;
            };
            if let Err(e) = almanac.rotate(Frame::new(301, 1), Frame::new(301, id), epoch) {
                notes.push(e.to_string());
            }
        }
    }

    /// Body `id`'s radii, IAU model and named frames, evaluated at J2000.
    fn rotation(kernels: &Kernels, id: i32, notes: &mut Vec<String>) {
        let _ = kernels.radii_km(id);
        let epoch = Epoch::from_tdb_seconds(0.0);
        let bodies = std::iter::once(SpiceBody::new(kernels, "body", id))
            .chain(FRAMES.map(|frame| SpiceBody::with_frame(kernels, "body", id, frame)));
        for body in bodies {
            match body {
                Ok(body) => {
                    if let Err(e) = body.frame.j2000_to_frame(kernels.almanac(), epoch) {
                        notes.push(e);
                    }
                }
                Err(e) => notes.push(e.to_string()),
            }
        }
    }
}

#[cfg(feature = "imaging")]
mod imaging {
    use super::{target, Outcome, Target};
    use std::path::Path;

    pub fn targets() -> Vec<Target> {
        vec![
            target("fits", read, cards(FITS_KEYWORDS)),
            Target {
                repair: Some(fix_png_crcs),
                ..target(
                    "png",
                    read,
                    &["tEXt", "IHDR", "slim:stretch\0linear 1e308 -1e308", "IEND"],
                )
            },
        ]
    }

    /// Header cards, padded to 80 characters by [`cards`].
    const FITS_KEYWORDS: &[&str] = &[
        "NAXIS   =                    3",
        "NAXIS   =  9223372036854775807",
        "NAXIS1  =           4294967296",
        "NAXIS2  =           4294967296",
        "NAXIS2  =  9223372036854775807",
        "NAXIS1  =                   -1",
        "NAXIS3  =                    1",
        "BITPIX  =                  -64",
        "BITPIX  =                    8",
        "BSCALE  =                1e308",
        "BZERO   =                  NaN",
        "END",
        "COMMENT = 'a '' quote / and a slash'",
        "BUNIT   = 'unterminated",
    ];

    /// `texts` as 80-character header cards (leaked: they live as long as the test).
    fn cards(texts: &[&str]) -> &'static [&'static str] {
        let cards: Vec<&'static str> = texts
            .iter()
            .map(|text| &*Box::leak(format!("{text:<80}").into_boxed_str()))
            .collect();
        cards.leak()
    }

    fn read(path: &Path) -> Outcome {
        Outcome::of(slim::image::read_image(path))
    }

    /// PNG chunks end in a CRC the decoder checks: recomputed, so that mutated headers and
    /// text reach the code behind the check.
    fn fix_png_crcs(data: &mut [u8]) {
        let mut at = 8;
        while let Some(length) = data.get(at..at + 4) {
            let length = u32::from_be_bytes(length.try_into().expect("4 bytes")) as usize;
            let Some(end) = (at + 8)
                .checked_add(length)
                .filter(|&e| e + 4 <= data.len())
            else {
                return;
            };
            let crc = crc32(&data[at + 4..end]);
            data[end..end + 4].copy_from_slice(&crc.to_be_bytes());
            at = end + 4;
        }
    }

    /// CRC-32 (ISO-HDLC, as PNG uses), bit by bit.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = (crc >> 1) ^ (0xEDB8_8320 & (crc & 1).wrapping_neg());
            }
        }
        !crc
    }
}

#[cfg(feature = "serve")]
mod service {
    use super::{target, Outcome, Target};
    use slim::serve::limits::Limits;
    use slim::serve::scene_input::{check_files, plan, scene_text};
    use std::path::{Path, PathBuf};
    use std::sync::OnceLock;

    pub fn targets() -> Vec<Target> {
        vec![
            Target {
                names_file: false,
                ..target("request", submit, super::SCENE_KEYWORDS)
            },
            Target {
                names_file: false,
                ..target(
                    "points",
                    points,
                    &[
                        "{\"facet\": 18446744073709551615}",
                        "[",
                        "]",
                        "null",
                        "\"targets\": ",
                    ],
                )
            },
        ]
    }

    /// The data folder requests are read against: the corpus itself (read-only), so that
    /// requests name corpus files as `obj/tetra.obj`, `spk/tiny-le.bsp`, `scene/...`.
    fn data_dir() -> &'static Path {
        static DIR: OnceLock<PathBuf> = OnceLock::new();
        DIR.get_or_init(|| super::corpus_dir().canonicalize().expect("corpus folder"))
    }

    fn content_type(path: &Path) -> Option<&'static str> {
        match path.extension()?.to_str()? {
            "json" => Some("application/json"),
            "toml" => Some("application/toml; charset=utf-8"),
            _ => None,
        }
    }

    /// What `POST /v1/jobs` does before accepting a job, without a server: the body as a
    /// scene, its files checked and, unless `SLIM_FUZZ_PLAN=0`, the scene planned.
    fn submit(path: &Path) -> Outcome {
        let body = std::fs::read(path).expect("case file");
        let dir = data_dir();
        let checked = scene_text(dir, "fuzz-case", content_type(path), &body).and_then(|text| {
            let scene = text.parse(dir)?;
            check_files(dir, &scene)?;
            if planning() {
                plan(dir, &text, &Limits::default())?;
            }
            Ok(())
        });
        Outcome::of(checked.map_err(|e| e.message))
    }

    fn planning() -> bool {
        std::env::var("SLIM_FUZZ_PLAN").map_or(true, |v| v != "0")
    }

    /// What `POST /v1/jobs/{id}/irradiance` reads from its body.
    fn points(path: &Path) -> Outcome {
        let body = std::fs::read(path).expect("case file");
        let request = slim::serve::points::PointsRequest::from_body(&body);
        Outcome::of(request.map_err(|e| e.message))
    }
}

// ---------------------------------------------------------------------------------------
// Checks

/// An error message must be one line a person can read: no line break or other control
/// character, not longer than [`MAX_MESSAGE_CHARS`] beyond the path, and, for a file
/// reader, naming the file.
fn check_message(message: &str, path: Option<&str>) -> Result<(), String> {
    let allowed = MAX_MESSAGE_CHARS + path.map_or(0, str::len);
    if message.trim().is_empty() {
        Err("the error message is empty".into())
    } else if let Some(c) = message.chars().find(|c| c.is_control()) {
        Err(format!(
            "the error message holds the control character {c:?}"
        ))
    } else if message.chars().count() > allowed {
        Err(format!(
            "the error message has {} characters (more than {allowed})",
            message.chars().count()
        ))
    } else if path.is_some_and(|p| !message.contains(p)) {
        Err("the error message does not name the file".into())
    } else {
        Ok(())
    }
}

/// The reasons case `outcome` fails the property, if any.
fn judge(outcome: &Outcome, peak: usize, input_bytes: usize, path: Option<&str>) -> Vec<String> {
    let mut problems = Vec::new();
    let bound = allocation_bound(input_bytes);
    if peak > bound {
        problems.push(format!("peak allocation {peak} bytes > bound {bound}"));
    }
    if let Some(refusal) = &outcome.refusal {
        if let Err(why) = check_message(refusal, path) {
            problems.push(format!("{why}: {refusal:?}"));
        }
    }
    for note in &outcome.notes {
        if let Err(why) = check_message(note, None) {
            problems.push(format!("query: {why}: {note:?}"));
        }
    }
    problems
}

static LAST_PANIC: std::sync::Mutex<String> = std::sync::Mutex::new(String::new());

/// Panics are caught per case; the hook keeps the message and place for the report
/// instead of printing them, with a backtrace when `RUST_BACKTRACE` asks for one (to
/// replay a case).
fn record_panics() {
    std::panic::set_hook(Box::new(|info| {
        let mut text = info.to_string().replace('\n', " ");
        let trace = std::backtrace::Backtrace::capture();
        if trace.status() == std::backtrace::BacktraceStatus::Captured {
            text.push_str(&format!("\n{trace}"));
        }
        *LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner()) = text;
    }));
}

// ---------------------------------------------------------------------------------------
// Campaign

fn corpus_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

fn env_number(name: &str) -> Option<u64> {
    let text = std::env::var(name).ok()?;
    Some(
        text.trim()
            .parse()
            .unwrap_or_else(|_| panic!("{name}={text}: not a whole number")),
    )
}

/// What the environment asks for.
struct Settings {
    base_seed: u64,
    /// Mutated cases per target, after its seeds.
    cases: usize,
    /// Only this case.
    replay: Option<usize>,
    only: Option<Vec<String>>,
}

impl Settings {
    fn from_env() -> Settings {
        Settings {
            base_seed: env_number("SLIM_FUZZ_SEED").unwrap_or(0),
            cases: env_number("SLIM_FUZZ_CASES").map_or(DEFAULT_CASES, |n| n as usize),
            replay: env_number("SLIM_FUZZ_REPLAY").map(|n| n as usize),
            only: std::env::var("SLIM_FUZZ_ONLY")
                .ok()
                .map(|s| s.split(',').map(|t| t.trim().to_string()).collect()),
        }
    }

    fn wants(&self, target: &Target) -> bool {
        self.only
            .as_ref()
            .is_none_or(|names| names.iter().any(|n| n == target.name))
    }
}

/// A seed file: its name (for the case file's extension) and bytes.
struct Seed {
    name: String,
    bytes: Vec<u8>,
}

fn seeds(target: &str) -> Vec<Seed> {
    let dir = corpus_dir().join(target);
    let mut seeds: Vec<Seed> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.expect("corpus entry").path();
            Seed {
                name: path.file_name().unwrap().to_string_lossy().into_owned(),
                bytes: std::fs::read(&path).expect("corpus file"),
            }
        })
        .collect();
    seeds.sort_by(|a, b| a.name.cmp(&b.name));
    assert!(!seeds.is_empty(), "no seeds in {}", dir.display());
    seeds
}

/// Every seed of the corpus, whatever the targets run (so that a case does not depend on
/// `SLIM_FUZZ_ONLY`): what splices take chunks from.
fn all_seeds() -> Vec<Seed> {
    let mut folders: Vec<PathBuf> = std::fs::read_dir(corpus_dir())
        .expect("corpus folder")
        .map(|entry| entry.expect("corpus entry").path())
        .filter(|path| path.is_dir())
        .collect();
    folders.sort();
    folders
        .iter()
        .flat_map(|folder| seeds(&folder.file_name().unwrap().to_string_lossy()))
        .collect()
}

/// The first failing case of a kind, and how many cases failed that way.
struct Failure {
    case: usize,
    seed_name: String,
    problems: Vec<String>,
    saved: PathBuf,
    count: usize,
}

/// What a target's campaign found.
#[derive(Default)]
struct Tally {
    cases: usize,
    refused: usize,
    /// The largest peak allocation and the slowest case, each with its case index.
    peak: (usize, usize),
    slowest: (Duration, usize),
    failing: usize,
    /// By kind ([`kind_of`]): a long campaign's thousands of failures that differ only in
    /// a byte show as one example each of the ways the property fails.
    failures: std::collections::BTreeMap<String, Failure>,
}

/// A failure's kind: its first problem without numbers and quoted input (a panic keeps
/// its place in the source).
fn kind_of(problems: &[String]) -> String {
    let first = problems.first().map_or("", String::as_str);
    let plain = first.split(['\'', '"', '`']).next().unwrap_or_default();
    plain
        .chars()
        .filter(|c| !c.is_ascii_digit())
        .collect::<String>()
        + first
            .strip_prefix("panic: ")
            .and_then(|p| p.split(": ").next())
            .unwrap_or_default()
}

/// Runs the seeds as they are (cases 0..seeds) and then mutated cases of `target`.
fn campaign(target: &Target, settings: &Settings, work: &Path, donors: &[Seed]) -> Tally {
    let seeds = seeds(target.name);
    let folder = work.join(target.name);
    std::fs::create_dir_all(&folder).expect("work folder");
    let mut tally = Tally::default();
    let cases = match settings.replay {
        Some(case) => case..case + 1,
        None => 0..seeds.len() + settings.cases,
    };
    for case in cases {
        let mut rng = case_rng(settings.base_seed, target.name, case);
        let (seed, input) = case_input(&mut rng, target, &seeds, donors, case);
        let path = folder.join(format!("case.{}", extension(&seed.name)));
        write_case(&path, &input);
        let label = format!(
            "fuzz target {} seed {} case {case}: input left in {}",
            target.name,
            settings.base_seed,
            path.display()
        );
        let started = Instant::now();
        let (outcome, peak) = meter::measure(label, || {
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (target.read)(&path)))
        });
        let took = started.elapsed();
        tally.cases += 1;
        tally.peak = tally.peak.max((peak, case));
        tally.slowest = tally.slowest.max((took, case));
        let shown_path = path.display().to_string();
        let problems = match outcome {
            Ok(outcome) => {
                tally.refused += usize::from(outcome.refusal.is_some());
                let named = target.names_file.then_some(shown_path.as_str());
                let mut problems = judge(&outcome, peak, input.len(), named);
                if took > SLOW_CASE {
                    problems.push(format!("took {took:?}"));
                }
                problems
            }
            Err(_) => vec![format!(
                "panic: {}",
                LAST_PANIC.lock().unwrap_or_else(|e| e.into_inner())
            )],
        };
        if !problems.is_empty() {
            note_failure(&mut tally, target, settings, case, seed, &input, problems);
        }
    }
    tally
}

/// Writes a case's input as a new file: rewriting the previous case's file in place
/// would make ext4 flush it to disk on close (`auto_da_alloc`), a disk wait per case.
fn write_case(path: &Path, input: &[u8]) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, input).expect("write case");
}

/// Case `case`'s seed and input: the seed itself for the first cases, then a mutation.
fn case_input<'a>(
    rng: &mut Rng,
    target: &Target,
    seeds: &'a [Seed],
    donors: &'a [Seed],
    case: usize,
) -> (&'a Seed, Vec<u8>) {
    if let Some(seed) = seeds.get(case) {
        return (seed, seed.bytes.clone());
    }
    let seed = rng.pick(seeds);
    let donor = if rng.one_in(4) {
        rng.pick(donors)
    } else {
        rng.pick(seeds)
    };
    let material = Material {
        seed: &seed.bytes,
        donor: &donor.bytes,
        keywords: target.keywords,
    };
    let mut input = make_input(rng, &material);
    if let Some(repair) = target.repair.filter(|_| !rng.one_in(4)) {
        repair(&mut input);
    }
    (seed, input)
}

fn extension(name: &str) -> &str {
    Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("bin")
}

/// Counts a failing case; the first of its kind is kept, its input saved in
/// `$TMPDIR/slim-fuzz-failures/`.
fn note_failure(
    tally: &mut Tally,
    target: &Target,
    settings: &Settings,
    case: usize,
    seed: &Seed,
    input: &[u8],
    problems: Vec<String>,
) {
    tally.failing += 1;
    let kind = kind_of(&problems);
    if let Some(known) = tally.failures.get_mut(&kind) {
        known.count += 1;
        return;
    }
    let folder = std::env::temp_dir().join("slim-fuzz-failures");
    let saved = folder.join(format!(
        "{}-seed{}-case{case}.{}",
        target.name,
        settings.base_seed,
        extension(&seed.name)
    ));
    let _ = std::fs::create_dir_all(&folder).and_then(|()| std::fs::write(&saved, input));
    let failure = Failure {
        case,
        seed_name: seed.name.clone(),
        problems,
        saved,
        count: 1,
    };
    tally.failures.insert(kind, failure);
}

/// A work folder, removed when the campaign ends.
struct WorkDir(PathBuf);

impl Drop for WorkDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn describe(target: &Target, tally: &Tally) -> String {
    format!(
        "{:8} {:>9} cases {:>9} refused  peak {:>5.1} MiB (case {:>7})  slowest {:>8.1?} \
         (case {:>7})  {} failing",
        target.name,
        tally.cases,
        tally.refused,
        tally.peak.0 as f64 / f64::from(1 << 20),
        tally.peak.1,
        tally.slowest.0,
        tally.slowest.1,
        tally.failing
    )
}

fn describe_failures(target: &Target, settings: &Settings, tally: &Tally) -> String {
    let mut text = String::new();
    for failure in tally.failures.values() {
        text.push_str(&format!(
            "\n{} case {}, first of {} alike (SLIM_FUZZ_SEED={} SLIM_FUZZ_ONLY={} \
             SLIM_FUZZ_REPLAY={}; from seed {}; input {}):\n    {}",
            target.name,
            failure.case,
            failure.count,
            settings.base_seed,
            target.name,
            failure.case,
            failure.seed_name,
            failure.saved.display(),
            failure.problems.join("\n    ")
        ));
    }
    text
}

#[test]
fn readers_survive_random_and_mutated_input() {
    let settings = Settings::from_env();
    let work = WorkDir(std::env::temp_dir().join(format!("slim-fuzz-{}", std::process::id())));
    let targets: Vec<Target> = targets()
        .into_iter()
        .filter(|t| settings.wants(t))
        .collect();
    let donors = all_seeds();
    record_panics();
    let started = Instant::now();
    let mut report = String::new();
    let (mut total, mut failing) = (0, 0);
    for target in &targets {
        let tally = campaign(target, &settings, &work.0, &donors);
        println!("{}", describe(target, &tally));
        total += tally.cases;
        failing += tally.failing;
        report.push_str(&describe_failures(target, &settings, &tally));
    }
    let _ = std::panic::take_hook();
    println!(
        "fuzz: {total} cases, seed {}, in {:.1?}",
        settings.base_seed,
        started.elapsed()
    );
    assert!(failing == 0, "{failing} failing cases:{report}");
}
