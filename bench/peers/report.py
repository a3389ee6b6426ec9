"""The peer benchmark's table.

In: a results folder laid out by `bench/peers/run`: one folder per case holding
`slim1/slim.json`, `slim2/slim.json` (slim with 1 and 2 threads), `embree.json`, and
slim's shadowed bitmaps of both runs; with `--pairs N`, also `round-2/` … `round-N/`,
each with the same three JSON files of a later round. Out: the table printed, and
`table.md` and `results.json` written into the results folder, stamped with the date,
the machine architecture and the CPU model. With rounds, a third table gives each
ratio's median and range over the rounds, every ratio taken within one round.
"""

import argparse
import datetime
import json
import platform
import sys
from pathlib import Path

import numpy as np


def cpu_model():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def load_case(folder):
    slim1 = json.loads((folder / "slim1" / "slim.json").read_text())
    slim2 = json.loads((folder / "slim2" / "slim.json").read_text())
    embree = json.loads((folder / "embree.json").read_text())
    same = np.array_equal(np.load(folder / "slim1" / "shadowed.npy"),
                          np.load(folder / "slim2" / "shadowed.npy"))
    return {
        "case": folder.name,
        "facets": slim1["facets"],
        "steps": slim1["steps"],
        "slim_1t_ms": slim1["ms_per_step_mean"],
        "slim_1t_min_ms": slim1["ms_per_step_min"],
        "slim_2t_ms": slim2["ms_per_step_mean"],
        "slim_2t_min_ms": slim2["ms_per_step_min"],
        "embree_1t_ms": embree["ms_per_step_mean"],
        "embree_1t_min_ms": embree["ms_per_step_min"],
        "embree_over_slim_1t": embree["ms_per_step_mean"] / slim1["ms_per_step_mean"],
        "slim_2t_speedup": slim1["ms_per_step_mean"] / slim2["ms_per_step_mean"],
        "slim_1t_rays_per_s": slim1["rays_per_s"],
        "slim_2t_rays_per_s": slim2["rays_per_s"],
        "embree_rays_per_s": embree["rays_per_s"],
        "rays_per_step": slim1["rays"] / slim1["steps"],
        "slim_rss_before_mb": slim1["memory"]["before_loop"]["vm_rss_mb"],
        "slim_1t_loop_growth_mb": slim1["memory"]["rss_growth_mb"],
        "slim_1t_peak_mb": slim1["memory"]["after_loop"]["vm_hwm_mb"],
        "slim_2t_loop_growth_mb": slim2["memory"]["rss_growth_mb"],
        "embree_build_growth_mb": embree["memory"]["rss_growth_mb"],
        "embree_build_hwm_growth_mb": embree["memory"]["hwm_growth_mb"],
        "embree_bvh_build_s": embree["bvh_build_s"],
        "embree_upload_s": embree["upload_s"],
        "slim_direct_new_s": slim1["direct_new_s"],
        "slim_tracer": slim1["tracer"],
        "slim_block": slim1.get("block", 1),
        "slim_build_growth_mb": slim1["memory"]["build_rss_growth_mb"],
        "slim_build_heap_mb": slim1["memory"].get("build_heap_growth_mb", float("nan")),
        "slim_above_horizon_share": slim1["above_horizon_facet_steps"]
        / max(1, slim1["traced_facet_steps"]),
        "slim_shadowed": slim1["shadowed_facet_steps"],
        "embree_shadowed": embree["shadowed_facet_steps"],
        "slim_1t_2t_identical": same,
        "disagreements": embree["disagreements"],
        "slim_shadowed_embree_lit": embree["slim_shadowed_embree_lit"],
        "embree_shadowed_slim_lit": embree["embree_shadowed_slim_lit"],
        "refereed": embree["refereed"],
        "referee_capped": embree["referee_capped"],
        "slim_right": embree["slim_right"],
        "embree_right": embree["embree_right"],
        "marginal": embree["marginal"],
        "referee_check": f"{embree['referee_check']['agree']}/{embree['referee_check']['rays']}",
        "tnear": embree["tnear"],
        "embree_os_threads": max(embree["os_threads_after_build"],
                                 embree["os_threads_after_tracing"]),
        "embree_cpu_over_wall": embree["tracing_cpu_over_wall"],
        "embree_version": embree["embree"],
        "rounds_ms": round_ratios(folder),
    }


def round_ratios(folder):
    """Per round of a case (the first, then `round-K/`), its three mean times per step
    (ms): slim 1 thread, slim 2 threads, Embree 1 thread."""
    rounds = [folder] + sorted(folder.glob("round-*"), key=lambda p: int(p.name[6:]))
    times = []
    for r in rounds:
        ms = [json.loads((r / name).read_text())["ms_per_step_mean"]
              for name in ("slim1/slim.json", "slim2/slim.json", "embree.json")]
        times.append(ms)
    return times


def spread_of(values):
    """Median and range of `values`, as 'median (min–max)'."""
    v = sorted(values)
    return f"{float(np.median(v)):.2f} ({v[0]:.2f}–{v[-1]:.2f})"


def rounds_table(rows):
    lines = [
        "| case | rounds | slim 1T ms/step | slim 2T ms/step | Embree 1T ms/step "
        "| Embree/slim 1T | Embree 1T / slim 2T | slim 2T speed-up |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        t = r["rounds_ms"]
        lines.append(
            f"| {r['case']} | {len(t)} | {spread_of([x[0] for x in t])} "
            f"| {spread_of([x[1] for x in t])} | {spread_of([x[2] for x in t])} "
            f"| {spread_of([x[2] / x[0] for x in t])} | {spread_of([x[2] / x[1] for x in t])} "
            f"| {spread_of([x[0] / x[1] for x in t])} |")
    return "\n".join(lines)


def setup_over_steps(r):
    """slim's setup on one thread (tree, bound, and a map built in the run) over the time
    Embree's one thread took for all the case's steps, in the same run."""
    return r["slim_direct_new_s"] / (r["embree_1t_ms"] * r["steps"] / 1e3)


def tables(rows):
    speed = [
        "| case | facets | steps | slim 1T ms/step | slim 2T ms/step | Embree 1T ms/step "
        "| Embree/slim 1T | slim 2T speed-up | rays/s slim 1T | rays/s slim 2T "
        "| rays/s Embree 1T |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    other = [
        "| case | slim setup s (1T) | slim setup / Embree's steps (1T) "
        "| slim built-once MB (heap) | slim loop growth MB (1T/2T) "
        "| slim peak MB | Embree geometry+BVH MB | Embree BVH build s "
        "| rays spared by the horizon bound | shadowed slim / Embree "
        "| disagreements (slim-only / Embree-only) | refereed | slim right | Embree right "
        "| near an edge | referee check |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        speed.append(
            f"| {r['case']} | {r['facets']:,} | {r['steps']} | {r['slim_1t_ms']:.2f} "
            f"| {r['slim_2t_ms']:.2f} | {r['embree_1t_ms']:.2f} "
            f"| {r['embree_over_slim_1t']:.2f} | {r['slim_2t_speedup']:.2f} "
            f"| {r['slim_1t_rays_per_s']:.2e} | {r['slim_2t_rays_per_s']:.2e} "
            f"| {r['embree_rays_per_s']:.2e} |")
        capped = " (capped)" if r["referee_capped"] else ""
        other.append(
            f"| {r['case']} | {r['slim_direct_new_s']:.2f} "
            f"| {setup_over_steps(r):.1f}× "
            f"| {r['slim_build_growth_mb']:.1f} ({r['slim_build_heap_mb']:.1f}) "
            f"| {r['slim_1t_loop_growth_mb']:.1f} / {r['slim_2t_loop_growth_mb']:.1f} "
            f"| {r['slim_1t_peak_mb']:.1f} | {r['embree_build_growth_mb']:.1f} "
            f"| {r['embree_bvh_build_s']:.2f} | {100 * r['slim_above_horizon_share']:.0f} % "
            f"| {r['slim_shadowed']:,} / {r['embree_shadowed']:,} "
            f"| {r['disagreements']:,} ({r['slim_shadowed_embree_lit']:,} / "
            f"{r['embree_shadowed_slim_lit']:,}) | {r['refereed']:,}{capped} "
            f"| {r['slim_right']:,} | {r['embree_right']:,} | {r['marginal']:,} "
            f"| {r['referee_check']} |")
    return "\n".join(speed), "\n".join(other)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("results", help="results folder of one run")
    ap.add_argument("--cases", required=True, help="comma-separated case names, in order")
    ap.add_argument("--note", default="", help="a line to add under the stamp")
    args = ap.parse_args()
    folder = Path(args.results)
    rows = []
    for name in args.cases.split(","):
        try:
            rows.append(load_case(folder / name))
        except FileNotFoundError as e:
            sys.exit(f"report: case {name} is incomplete: {e}")
    stamp = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "logical_cpus": len(__import__("os").sched_getaffinity(0)),
        "embree": rows[0]["embree_version"] if rows else "",
        "tnear": {r["case"]: r["tnear"] for r in rows},
        "note": args.note,
    }
    speed, other = tables(rows)
    stamp["slim_tracer"] = rows[0]["slim_tracer"] if rows else ""
    sizes = sorted({r["slim_block"] for r in rows})
    if sizes == [1] or not sizes:
        blocks = ""
    elif len(sizes) == 1:
        blocks = f" in blocks of {sizes[0]} steps"
    else:
        blocks = " in blocks of " + ", ".join(
            f"{r['slim_block']} steps ({r['case']})" for r in rows)
    header = (f"Peer benchmark, slim tracer {stamp['slim_tracer']}{blocks}, {stamp['date']}, "
              f"{stamp['machine']}, {stamp['cpu']}, "
              f"{stamp['logical_cpus']} logical CPUs, {stamp['embree']}")
    notes = [
        "1T/2T: slim with 1 or 2 rayon threads; Embree (embreex, rtcOccluded1 per ray) on "
        "one thread; the one-thread runs of both pinned to the same CPU.",
        "ms/step: mean over the steps (with --block K, slim computes K steps at a time, "
        "as slim run does, each step taking the block's time over K; Embree casts each "
        "step's rays in turn); slim's includes its per-step tracer build (sunview; "
        "the bvh tracer and its horizon bound are built once, 'slim setup s'; so is a "
        "horizon map, map-exact and map-approximate, unless read from the cache), "
        "Embree's is queries only (its BVH is built once, column 'Embree BVH build s').",
        "slim 2T speed-up = slim 1T ms / slim 2T ms. Embree/slim 1T > 1: slim faster.",
        "slim setup / Embree's steps: slim's setup on one thread (with a horizon map built "
        "in the run, the map's build) over Embree's one thread's time for all the case's "
        "steps (the horizon issue's build target is at most 1× for 360 steps).",
        "Memory: slim's RSS growth while building its tracer (built once; in parentheses "
        "the bytes its allocations hold, counted) and over the step loop (per-step "
        "structures); Embree's RSS growth over geometry upload + BVH build. Both sides "
        "read the build's growth after handing the heap's free pages back to the system "
        "(glibc malloc_trim), so it is what the structures keep, not freed temporaries.",
        "Disagreements: traced facet-steps where the two classify differently; each refereed"
        " one is settled by an f64 Möller–Trumbore test against all other facets "
        "(map-approximate decides from the map alone: its disagreements are its error).",
    ]
    if not all(r["slim_1t_2t_identical"] for r in rows):
        notes.append("WARNING: slim's 1- and 2-thread classifications differ for: "
                     + ", ".join(r["case"] for r in rows if not r["slim_1t_2t_identical"]))
    if args.note:
        notes.insert(0, args.note)
    parts = [header, speed, other]
    if any(len(r["rounds_ms"]) > 1 for r in rows):
        parts.append(rounds_table(rows))
        notes.append("Rounds (--pairs): each case run again in turn (slim 1T, slim 2T, "
                     "Embree 1T), timings only; each ratio is taken within a round, then "
                     "its median and range (min–max) over the rounds are given.")
    text = "\n\n".join(parts + ["\n".join("- " + n for n in notes)])
    print(text)
    (folder / "table.md").write_text(f"# Peer benchmark\n\n{text}\n")
    (folder / "results.json").write_text(
        json.dumps({"stamp": stamp, "cases": rows}, indent=2) + "\n")
    print(f"\nwritten: {folder / 'table.md'}, {folder / 'results.json'}")


if __name__ == "__main__":
    main()
