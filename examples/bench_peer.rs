//! Slim's half of the peer benchmark (`bench/peers/`): times a shadow tracer over a spin
//! and exports everything a peer ray tracer needs to cast the same rays.
//!
//! ```text
//! cargo run --release --example bench_peer -- [MESH] [--subdivide N] [--folded]
//!     [--steps N] [--threads N] [--tracer sunview|bvh|map-exact|map-approximate]
//!     [--cache DIR] [--bound-cache DIR] [--block K|run] [--whole-map] --out DIR
//! ```
//! In: a mesh file in km (default: the 49,152-facet Itokawa model) or `--folded` (the
//! bilobed test shape of `examples/common/folded.rs`), optionally subdivided (×4 facets
//! per level); `--steps` states over one spin about z with the Sun along +x in the
//! equator plane, as `bench_direct` uses. Only the step loop is timed, with the per-step
//! tracer build included (`--tracer sunview`, the default) or the tracer built once with
//! its horizon bound before the loop (`--tracer bvh`, reported as `direct_new_s`; with
//! `--tracer bvh-sectors`, read from `--bound-cache DIR` when it is there), or a
//! horizon map of 128 wedges looked up instead of tracing (`map-exact`: rays only where
//! the map is not certain, the same classification as the tracers; `map-approximate`:
//! no rays), built as `slim run` builds it, for the band of the steps' Suns
//! (`slim::horizon::band`; `--whole-map`: for every direction), its build (or its read
//! from `--cache DIR`) in `direct_new_s`. The
//! exports happen after the loop. Steps are computed one at a time, or with `--block K`
//! in blocks of K (`Direct::compute_steps`), with `--block run` in the blocks `slim run`
//! takes for the mesh (`slim::simulate::steps_per_batch`: 64 steps up to 262,144 facets,
//! 16 at a million), each step of a block given the block's time over K. The rays
//! recall the blockers of the earlier step `slim run` would pick (over one spin, the step
//! before: `slim::ephemeris::sun_return`), and under the whole bound remember them where
//! it would (steps up to 3° apart).
//!
//! Out, in DIR: `.npy` files (NumPy format 1.0, little-endian, C order) and `slim.json`.
//! - `vertices.npy` f64 (V, 3), metres; `triangles.npy` u32 (F, 3), 0-based;
//! - `normals.npy`, `centroids.npy` f64 (F, 3): slim's unit normals and ray origins;
//! - `min_height.npy` f64 (F): slim's least blocker height; the ray of facet i at Sun
//!   cosine c counts hits at distance t > min_height[i] / c only (`Direct::t_min`);
//! - `sun.npy` f64 (steps, 3): the unit Sun direction of each step, body frame;
//! - `traced.npy`, `shadowed.npy` u8 (steps, ceil(F/8)): bitmaps, bit i of row s is
//!   `byte[i / 8] >> (i % 8) & 1` (NumPy's `unpackbits(..., bitorder="little")`).
//!   Traced: n·s > 0 (a ray was cast); shadowed: traced and irradiance 0;
//! - `step_ms.npy` f64 (steps): time of each step;
//! - `slim.json`: counts, times, rays per second and memory (see [`summary`]).

// Shared by several benchmarks; each uses part of it.
#[allow(dead_code)]
mod common;

use glam::DVec3;
use slim::budget::Budget;
use slim::ephemeris::{EpochState, SunReturn};
use slim::horizon::bound::BoundDetail;
use slim::horizon::shadows::{recall_for_run, HorizonMode, ShadowMethod, Shadows};
use slim::illum::{Direct, StepCounts};
use slim::trace::TracerKind;
use slim::world::World;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

const VALUE_FLAGS: &[&str] = &[
    "--subdivide",
    "--steps",
    "--threads",
    "--out",
    "--tracer",
    "--cache",
    "--bound-cache",
    "--block",
];
const SWITCHES: &[&str] = &["--folded", "--whole-map"];

/// Memory figures of this process at one moment, MB.
#[derive(Clone, Copy)]
struct Memory {
    hwm_mb: f64,
    rss_mb: f64,
    /// Bytes allocated and not yet freed ([`heap::live_bytes`]), MB.
    heap_mb: f64,
}

impl Memory {
    fn now() -> Memory {
        Memory {
            hwm_mb: common::proc_status_mb("VmHWM:"),
            rss_mb: common::proc_status_mb("VmRSS:"),
            heap_mb: heap::live_bytes() as f64 / (1024.0 * 1024.0),
        }
    }

    /// [`Memory::now`] once the allocator has handed the build's freed temporaries back
    /// to the system, so that the resident growth is what the structures keep (the
    /// peer's side does the same).
    fn settled() -> Memory {
        heap::release_free();
        Memory::now()
    }

    fn json(self) -> serde_json::Value {
        serde_json::json!({
            "vm_hwm_mb": self.hwm_mb,
            "vm_rss_mb": self.rss_mb,
            "heap_mb": self.heap_mb,
        })
    }
}

/// The process's heap as the memory figures need it: the bytes allocated and not freed
/// (counted by a wrapper around the system allocator, exact whatever the allocator keeps
/// for reuse), and a way to give freed memory back. The library forbids `unsafe`; a
/// global allocator and a C call need it, so they live here, in the benchmark only.
mod heap {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::sync::atomic::{AtomicUsize, Ordering};

    static LIVE: AtomicUsize = AtomicUsize::new(0);

    /// The system allocator, counting what is held.
    struct Counting;

    // SAFETY: every call is passed to `System` unchanged; the counter is only arithmetic.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
            System.alloc(layout)
        }
        unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
            System.alloc_zeroed(layout)
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            System.dealloc(ptr, layout)
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            LIVE.fetch_add(new_size, Ordering::Relaxed);
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            System.realloc(ptr, layout, new_size)
        }
    }

    #[global_allocator]
    static GLOBAL: Counting = Counting;

    /// Bytes allocated and not yet freed.
    pub fn live_bytes() -> usize {
        LIVE.load(Ordering::Relaxed)
    }

    /// Returns the heap's free pages to the system (glibc's `malloc_trim`; a no-op
    /// elsewhere), so that resident memory counts what is held, not what was.
    pub fn release_free() {
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        {
            extern "C" {
                fn malloc_trim(pad: usize) -> i32;
            }
            // SAFETY: glibc's malloc_trim takes a byte count and touches only the heap's
            // free lists.
            unsafe {
                malloc_trim(0);
            }
        }
    }
}

/// One array to write as `.npy`: its NumPy type string, shape and little-endian bytes.
fn write_npy(path: &Path, descr: &str, shape: &[usize], bytes: &[u8]) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Magic (6) + version (2) + length (2) + header + '\n' is padded to a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat(unpadded.next_multiple_of(64) - unpadded));
    header.push('\n');
    let mut w = BufWriter::new(std::fs::File::create(path)?);
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&(header.len() as u16).to_le_bytes())?;
    w.write_all(header.as_bytes())?;
    w.write_all(bytes)?;
    w.flush()
}

fn f64_bytes(values: impl Iterator<Item = f64>) -> Vec<u8> {
    values.flat_map(f64::to_le_bytes).collect()
}

fn vec3_bytes(values: &[DVec3]) -> Vec<u8> {
    f64_bytes(values.iter().flat_map(|v| v.to_array()))
}

/// The direct stage with a horizon map of the body in `mode` for the Suns of `states`
/// (built, or read from `--cache DIR`).
fn with_map<'w>(
    world: &'w World,
    (mode, states): (HorizonMode, &[EpochState]),
    recall: SunReturn,
    options: &common::Options,
) -> Result<Direct<'w>, Box<dyn std::error::Error>> {
    let mut shadows = Shadows {
        method: ShadowMethod::Horizon,
        mode,
        cache_dir: options.optional("--cache")?,
        recall,
        ..Shadows::default()
    };
    if !options.has("--whole-map") {
        shadows.bands = shadows.bands_for_run(world, states);
    }
    Ok(common::mapped_direct(world, &shadows)?)
}

/// The body: `--folded` or the mesh file, subdivided by `--subdivide`.
fn build_world(options: &common::Options) -> Result<(World, String), Box<dyn std::error::Error>> {
    let levels: u32 = options.value("--subdivide", 0)?;
    if options.has("--folded") {
        if options.positional().is_some() {
            return Err("give either a mesh file or --folded, not both".into());
        }
        let world = options.world_from(common::folded::folded_raw()?, 0)?;
        return Ok((
            world,
            format!("folded (Phobos + Itokawa×25), subdivide {levels}"),
        ));
    }
    let path = options.mesh();
    if !path.is_file() {
        return Err(format!("mesh file {} not found", path.display()).into());
    }
    let world = options.world(0)?;
    Ok((world, format!("{}, subdivide {levels}", path.display())))
}

fn main() {
    if let Err(e) = run() {
        eprintln!("bench_peer: {e}");
        eprintln!(
            "usage: bench_peer [MESH] [--subdivide N] [--folded] [--steps N] [--threads N] \
             --out DIR"
        );
        std::process::exit(2);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let options = common::Options::from_env(VALUE_FLAGS);
    options.check(SWITCHES)?;
    let steps: usize = options.value("--steps", 360)?;
    if steps == 0 {
        return Err("--steps must be at least 1".into());
    }
    let _: u32 = options.value("--subdivide", 0)?;
    // `None`: the blocks `slim run` takes, known once the mesh is read.
    let block: Option<usize> = match options.value("--block", "1".to_string())?.as_str() {
        "run" => None,
        k => match k.parse::<usize>() {
            Ok(k) if k > 0 => Some(k),
            _ => {
                return Err(
                    format!("--block takes a step count of 1 or more, or run, not {k}").into(),
                )
            }
        },
    };
    let out_dir: PathBuf = options
        .optional::<String>("--out")?
        .ok_or("--out DIR is required")?
        .into();
    options.apply_threads()?;
    std::fs::create_dir_all(&out_dir)
        .map_err(|e| format!("cannot create {}: {e}", out_dir.display()))?;

    let (world, label) = build_world(&options)?;
    let block = block.unwrap_or_else(|| {
        slim::simulate::steps_per_batch(None, false, false, world.facet_count())
    });
    let states = common::spin_states(steps, DVec3::X)?;
    let body = &world.bodies[0];
    let mesh = &body.mesh;
    let facets = mesh.len();
    let threads = rayon::current_num_threads();
    println!("slim: {label}: {facets} facets, {steps} steps, {threads} threads");

    let tracer: String = options.value("--tracer", "sunview".to_string())?;
    let before_build = Memory::settled();
    let build_t0 = Instant::now();
    // The earlier step whose blockers the rays recall, as `slim run` finds it.
    let recall = recall_for_run(
        &world,
        &states,
        Budget::machine().remembered_blocker_bytes(),
    );
    let direct = match tracer.as_str() {
        "sunview" => Direct::new(&world, TracerKind::Sunview),
        "bvh" => {
            let shadows = Shadows {
                recall,
                ..Shadows::default()
            };
            let none = world.bodies.iter().map(|_| None).collect();
            Direct::with_maps(&world, TracerKind::Bvh, none, &shadows)
        }
        "bvh-sectors" => {
            // The bound a run takes when its steps pay for the sectors (`choice`).
            // Read from `--bound-cache DIR` when it holds this bound (to time the step
            // loop of several builds without building the bound each time; the peer
            // harness leaves it out, so that its setup is always a build).
            let shadows = Shadows {
                bound_detail: BoundDetail::Sectors,
                cache_dir: options.optional("--bound-cache")?,
                recall,
                ..Shadows::default()
            };
            let none = world.bodies.iter().map(|_| None).collect();
            Direct::with_maps(&world, TracerKind::Bvh, none, &shadows)
        }
        "map-exact" => with_map(&world, (HorizonMode::Exact, &states), recall, &options)?,
        "map-approximate" => with_map(
            &world,
            (HorizonMode::Approximate, &states),
            recall,
            &options,
        )?,
        t => {
            return Err(format!(
                "unknown --tracer {t} (sunview, bvh, bvh-sectors, map-exact, \
                     map-approximate)"
            )
            .into())
        }
    };
    let build_s = build_t0.elapsed().as_secs_f64();
    let after_build = Memory::settled();
    let min_height: Vec<f64> = (0..facets).map(|i| direct.t_min(0, i, 1.0)).collect();

    // Everything the loop writes is allocated and touched before the "before" reading,
    // so the growth is the tracer's own per-step structures.
    let row = facets.div_ceil(8);
    let mut traced = vec![1u8; steps * row];
    let mut shadowed = vec![1u8; steps * row];
    traced.fill(0);
    shadowed.fill(0);
    let mut step_ms = vec![0.0; steps];
    let mut outs = vec![vec![1.0; facets]; block];
    let before = Memory::now();

    let mut counts = StepCounts::default();
    for (b, chunk) in states.chunks(block).enumerate() {
        let first = b * block;
        let t0 = Instant::now();
        // (`Direct::compute` is this with a block of one step.)
        let mut views: Vec<&mut [f64]> = outs
            .iter_mut()
            .take(chunk.len())
            .map(|o| &mut o[..])
            .collect();
        let c = direct.compute_steps(chunk, &mut views)?;
        // A block's steps share its time evenly.
        let ms = 1e3 * t0.elapsed().as_secs_f64() / chunk.len() as f64;
        step_ms[first..first + chunk.len()].fill(ms);
        counts += c;
        // Classification, outside the timed part.
        for (k, (state, out)) in chunk.iter().zip(&outs).enumerate() {
            let s = first + k;
            let sun = state.bodies[0].sun_dir;
            let (t_row, s_row) = (
                &mut traced[s * row..(s + 1) * row],
                &mut shadowed[s * row..(s + 1) * row],
            );
            for i in 0..facets {
                if mesh.normals[i].dot(sun) > 0.0 {
                    t_row[i / 8] |= 1 << (i % 8);
                    if out[i] == 0.0 {
                        s_row[i / 8] |= 1 << (i % 8);
                    }
                }
            }
        }
    }
    let after = Memory::now();

    let loop_s: f64 = step_ms.iter().sum::<f64>() / 1e3;
    let bitmap_shadowed: u64 = shadowed.iter().map(|b| b.count_ones() as u64).sum();
    let bitmap_traced: u64 = traced.iter().map(|b| b.count_ones() as u64).sum();
    if bitmap_shadowed != counts.shadowed {
        return Err(format!(
            "shadowed bitmap counts {bitmap_shadowed} facet-steps, the tracer {}",
            counts.shadowed
        )
        .into());
    }

    let tri_bytes: Vec<u8> = mesh
        .triangles
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let suns: Vec<DVec3> = states.iter().map(|s| s.bodies[0].sun_dir).collect();
    let npy = |name: &str, descr: &str, shape: &[usize], bytes: &[u8]| {
        let path = out_dir.join(name);
        write_npy(&path, descr, shape, bytes)
            .map_err(|e| format!("cannot write {}: {e}", path.display()))
    };
    npy(
        "vertices.npy",
        "<f8",
        &[mesh.vertices.len(), 3],
        &vec3_bytes(&mesh.vertices),
    )?;
    npy("triangles.npy", "<u4", &[facets, 3], &tri_bytes)?;
    npy(
        "normals.npy",
        "<f8",
        &[facets, 3],
        &vec3_bytes(&mesh.normals),
    )?;
    npy(
        "centroids.npy",
        "<f8",
        &[facets, 3],
        &vec3_bytes(&mesh.centroids),
    )?;
    npy(
        "min_height.npy",
        "<f8",
        &[facets],
        &f64_bytes(min_height.iter().copied()),
    )?;
    npy("sun.npy", "<f8", &[steps, 3], &vec3_bytes(&suns))?;
    npy("traced.npy", "|u1", &[steps, row], &traced)?;
    npy("shadowed.npy", "|u1", &[steps, row], &shadowed)?;
    npy(
        "step_ms.npy",
        "<f8",
        &[steps],
        &f64_bytes(step_ms.iter().copied()),
    )?;

    let summary = summary(&Summary {
        tracer: &tracer,
        label: &label,
        world: &world,
        steps,
        threads,
        block,
        build_s,
        loop_s,
        step_ms: &step_ms,
        counts,
        traced: bitmap_traced,
        build: (before_build, after_build),
        before,
        after,
    });
    let json_path = out_dir.join("slim.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&summary)? + "\n")
        .map_err(|e| format!("cannot write {}: {e}", json_path.display()))?;
    println!(
        "slim: {:.3} ms/step (min {:.3}), {:.3e} rays/s, {} shadowed facet-steps, \
         RSS {:.1} → {:.1} MB",
        1e3 * loop_s / steps as f64,
        summary["ms_per_step_min"].as_f64().unwrap_or(0.0),
        counts.rays as f64 / loop_s,
        counts.shadowed,
        before.rss_mb,
        after.rss_mb
    );
    Ok(())
}

/// What `slim.json` is made from.
struct Summary<'a> {
    tracer: &'a str,
    label: &'a str,
    world: &'a World,
    steps: usize,
    threads: usize,
    /// Steps computed together (`--block`).
    block: usize,
    build_s: f64,
    loop_s: f64,
    step_ms: &'a [f64],
    counts: StepCounts,
    traced: u64,
    build: (Memory, Memory),
    before: Memory,
    after: Memory,
}

/// `slim.json`: facets, steps, threads; `direct_new_s` (`Direct::new`, outside the loop);
/// `loop_s`, `ms_per_step_mean`, `ms_per_step_min`; `rays` (shadow queries the tracer
/// counted), `rays_per_s`, `traced_facet_steps` (n·s > 0), `shadowed_facet_steps`,
/// `night_facet_steps`, `above_horizon_facet_steps` (answered by the horizon bound, no
/// ray), `remembered_facet_steps` (shadowed rays whose blocker the walk from the step
/// before's found, no tree), `walks` (rays that walked, finding a blocker or not);
/// memory `before_loop` and `after_loop` (VmHWM = peak, VmRSS = current, MB), their
/// growth, and the growth over the build (the tracer's structures built once):
/// `build_rss_growth_mb`, resident, read after the build's freed temporaries went back
/// to the system, and `build_heap_growth_mb`, the bytes allocated and held.
fn summary(s: &Summary<'_>) -> serde_json::Value {
    let body = &s.world.bodies[0];
    let min_ms = s.step_ms.iter().copied().fold(f64::INFINITY, f64::min);
    serde_json::json!({
        "tracer": s.tracer,
        "shape": s.label,
        "facets": body.mesh.len(),
        "vertices": body.mesh.vertices.len(),
        "convex": body.convex,
        "bounding_radius_m": body.bounding_radius_m,
        "steps": s.steps,
        "threads": s.threads,
        "block": s.block,
        "direct_new_s": s.build_s,
        "loop_s": s.loop_s,
        "ms_per_step_mean": 1e3 * s.loop_s / s.steps as f64,
        "ms_per_step_min": min_ms,
        "rays": s.counts.rays,
        "rays_per_s": s.counts.rays as f64 / s.loop_s,
        "traced_facet_steps": s.traced,
        "shadowed_facet_steps": s.counts.shadowed,
        "night_facet_steps": s.counts.night,
        "above_horizon_facet_steps": s.counts.above_horizon,
        "remembered_facet_steps": s.counts.remembered,
        "walks": s.counts.walks,
        "memory": {
            "before_loop": s.before.json(),
            "after_loop": s.after.json(),
            "hwm_growth_mb": s.after.hwm_mb - s.before.hwm_mb,
            "rss_growth_mb": s.after.rss_mb - s.before.rss_mb,
            "build_rss_growth_mb": s.build.1.rss_mb - s.build.0.rss_mb,
            "build_heap_growth_mb": s.build.1.heap_mb - s.build.0.heap_mb,
        },
    })
}
