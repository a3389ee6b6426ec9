"""Embree's half of the peer benchmark, and the facet-by-facet comparison with slim.

In: a folder written by `examples/bench_peer.rs` (the mesh slim used, its normals,
centroids and least blocker heights, the Sun of every step, and slim's traced and
shadowed bitmaps; see that file's doc for the format).

What it does:
1. Builds one Embree scene over the mesh (f64 coordinates rounded to f32), robust mode,
   and reports the geometry upload (embreex copies the arrays element by element in
   Python-level code) and the BVH build (`rtcCommitScene`) separately, with the resident
   memory they added (read after the heap's free pages went back to the system, as
   slim's half reads its own).
2. Per step, casts an occlusion ray for exactly the facets slim traced (n·s > 0, read
   from slim's bitmap): origin the facet centroid, direction the Sun. embreex fixes the
   ray's tnear at 0 and cannot skip a facet by id, so the ray's start is moved along
   the Sun direction by tnear (see `tnear`) before rounding to f32: the segment
   [tnear, inf) of the true ray. Only the `scene.run(..., query="OCCLUDED")` call is
   timed; embreex runs it as a plain loop of `rtcOccluded1` on the calling thread.
3. Compares Embree's answer with slim's for every traced facet-step, and settles each
   disagreement (up to `--cap`, evenly spread if there are more) with an independent
   f64 test (`referee`), plus a sample of agreeing rays as a check of the referee.

Out: a JSON summary (`--out`) and a CSV of the refereed disagreements beside it.
"""

import argparse
import csv
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

F32_EPS = float(np.finfo(np.float32).eps)


def status_mb(key):
    """A memory line of /proc/self/status (e.g. 'VmRSS:'), MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0
    return 0.0


def memory():
    return {"vm_hwm_mb": status_mb("VmHWM:"), "vm_rss_mb": status_mb("VmRSS:")}


def settled_memory():
    """`memory()` once the C heap's free pages went back to the system (glibc's
    malloc_trim), so that the growth is what the scene keeps, not the build's freed
    temporaries; slim's half reads its memory the same way."""
    try:
        import ctypes
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass  # not glibc: the figure is read as it is
    return memory()


def os_threads():
    """Number of OS threads of this process right now."""
    return len(os.listdir("/proc/self/task"))


def unpack(row, n):
    """One row of a little-endian bitmap as a bool array of length n."""
    return np.unpackbits(row, bitorder="little")[:n].astype(bool)


class Case:
    """The arrays slim exported."""

    def __init__(self, folder):
        folder = Path(folder)
        missing = [
            name
            for name in (
                "vertices", "triangles", "normals", "centroids", "min_height",
                "sun", "traced", "shadowed",
            )
            if not (folder / f"{name}.npy").is_file()
        ]
        if missing:
            sys.exit(f"embree_peer: {folder} lacks {', '.join(m + '.npy' for m in missing)}"
                     " (run bench_peer first)")
        load = lambda name: np.load(folder / f"{name}.npy")
        self.vertices = load("vertices")
        self.triangles = load("triangles")
        self.normals = load("normals")
        self.centroids = load("centroids")
        self.min_height = load("min_height")
        self.sun = load("sun")
        self.traced = load("traced")
        self.shadowed = load("shadowed")
        self.slim = json.loads((folder / "slim.json").read_text())
        self.facets = len(self.triangles)
        self.steps = len(self.sun)
        # Size of the body: what f32 rounding of its coordinates is relative to.
        self.radius = float(np.sqrt((self.vertices**2).sum(axis=1)).max())
        self.longest_edge = None

    def measure_edges(self):
        """Longest edge of every facet (after the scene build, so that the temporaries
        do not blur Embree's memory figure)."""
        longest = np.zeros(self.facets)
        for lo in range(0, self.facets, 1 << 18):
            corners = self.vertices[self.triangles[lo:lo + (1 << 18)]]  # (n, 3, 3)
            edges = corners - np.roll(corners, 1, axis=1)
            longest[lo:lo + len(corners)] = np.sqrt((edges**2).sum(axis=2)).max(axis=1)
        self.longest_edge = longest


def tnear(case, idx, cos, ulps):
    """Where Embree's ray starts along the Sun direction, per traced facet.

    Slim's own t_min (min_height / cos), or, where f32 needs more room to step off the
    facet, `ulps` f32 roundings of the body's size taken as a height above the facet's
    plane (so divided by the Sun cosine, like slim's t_min) and capped at the facet's
    longest edge (a ray from the centroid leaves its own facet's footprint within about
    that distance, so a longer skip would only hide real blockers).
    """
    f32_room = np.minimum(ulps * F32_EPS * case.radius / cos, case.longest_edge[idx])
    return np.maximum(case.min_height[idx] / cos, f32_room)


def build_scene(case):
    from embreex import mesh_construction, rtcore, rtcore_scene

    vertices = np.ascontiguousarray(case.vertices, dtype=np.float32)
    triangles = np.ascontiguousarray(case.triangles, dtype=np.int32)
    probe_origin = np.zeros((1, 3), np.float32)
    probe_dir = np.array([[0.0, 0.0, 1.0]], np.float32)
    before = settled_memory()
    threads_before = os_threads()
    t0 = time.perf_counter()
    device = rtcore.EmbreeDevice()
    scene = rtcore_scene.EmbreeScene(device, robust=True)
    geometry = mesh_construction.TriangleMesh(scene, vertices, triangles)
    t1 = time.perf_counter()
    # embreex commits the scene (builds the BVH) on the first query.
    scene.run(probe_origin, probe_dir, query="OCCLUDED")
    t2 = time.perf_counter()
    after = settled_memory()
    info = {
        "embree": repr(device),
        "upload_s": t1 - t0,
        "bvh_build_s": t2 - t1,
        "memory": {
            "before_build": before,
            "after_build": after,
            "rss_growth_mb": after["vm_rss_mb"] - before["vm_rss_mb"],
            "hwm_growth_mb": after["vm_hwm_mb"] - before["vm_hwm_mb"],
        },
        "os_threads_before_build": threads_before,
        "os_threads_after_build": os_threads(),
    }
    return scene, (device, geometry), info


class Referee:
    """Independent f64 shadow test: Möller–Trumbore against every triangle but the
    ray's own facet, a hit counting when t > slim's t_min (edges and corners count).

    Per step, triangles whose box in the plane across the Sun cannot contain the ray
    are skipped first (a conservative cull, padded; it never decides a hit).
    """

    def __init__(self, case):
        self.case = case
        c = case.vertices[case.triangles]
        self.v0 = c[:, 0]
        self.e1 = c[:, 1] - c[:, 0]
        self.e2 = c[:, 2] - c[:, 0]
        self.step = None
        self.pad = 1e-7 * case.radius

    def _prepare(self, step):
        d = self.case.sun[step]
        a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(d, a)
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        proj = self.case.vertices @ np.stack([u, w], axis=1)  # (V, 2)
        corners = proj[self.case.triangles]  # (F, 3, 2)
        self.lo = corners.min(axis=1) - self.pad
        self.hi = corners.max(axis=1) + self.pad
        self.uw = np.stack([u, w], axis=1)
        self.d = d
        self.step = step

    def test(self, step, facet):
        """(blocked, margin, t): margin is the best barycentric margin min(u, v, 1-u-v)
        over triangles beyond t_min (>= 0: hit, < 0: nearest miss), t its distance."""
        if self.step != step:
            self._prepare(step)
        case, d = self.case, self.d
        o = case.centroids[facet]
        cos = float(case.normals[facet] @ d)
        t_min = case.min_height[facet] / cos
        q = o @ self.uw
        cand = np.flatnonzero(
            (self.lo[:, 0] <= q[0]) & (self.hi[:, 0] >= q[0])
            & (self.lo[:, 1] <= q[1]) & (self.hi[:, 1] >= q[1])
        )
        cand = cand[cand != facet]
        if cand.size == 0:
            return False, -np.inf, np.nan
        e1, e2, v0 = self.e1[cand], self.e2[cand], self.v0[cand]
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = det != 0.0
        e1, e2, v0, p, det = e1[ok], e2[ok], v0[ok], p[ok], det[ok]
        if det.size == 0:
            return False, -np.inf, np.nan
        tv = o - v0
        u = np.einsum("ij,ij->i", tv, p) / det
        qv = np.cross(tv, e1)
        v = (qv @ d) / det
        t = np.einsum("ij,ij->i", e2, qv) / det
        margin = np.minimum(np.minimum(u, v), 1.0 - u - v)
        beyond = t > t_min
        if not beyond.any():
            return False, -np.inf, np.nan
        k = np.flatnonzero(beyond)[np.argmax(margin[beyond])]
        return bool(margin[k] >= 0.0), float(margin[k]), float(t[k])


def spread(indices, cap):
    """At most `cap` of `indices`, evenly spread, deterministic."""
    if len(indices) <= cap:
        return list(indices)
    picks = np.linspace(0, len(indices) - 1, cap).round().astype(int)
    return [indices[k] for k in picks]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, help="folder written by bench_peer")
    ap.add_argument("--out", required=True, help="JSON summary to write")
    ap.add_argument("--tnear-ulps", type=float, default=4.0,
                    help="ray start, in f32 roundings of the body size above the facet "
                         "plane (default 4)")
    ap.add_argument("--cap", type=int, default=2000,
                    help="most disagreements to settle with the f64 test (default 2000)")
    ap.add_argument("--check-agreements", type=int, default=200,
                    help="agreeing rays also run through the f64 test (default 200)")
    args = ap.parse_args()

    case = Case(args.data)
    scene, keep_alive, build = build_scene(case)
    case.measure_edges()
    print(f"embree: {build['embree']}, {case.facets} facets, upload {build['upload_s']:.2f} s,"
          f" BVH build {build['bvh_build_s']:.3f} s,"
          f" RSS +{build['memory']['rss_growth_mb']:.1f} MB")

    step_ms = []
    rays = 0
    cpu_s = 0.0
    disagreements = []  # (step, facet, slim_blocked, embree_blocked, cos)
    agreements = {True: [], False: []}
    embree_shadowed = 0
    slim_shadowed = 0
    for s in range(case.steps):
        d = case.sun[s]
        traced = unpack(case.traced[s], case.facets)
        slim_blocked = unpack(case.shadowed[s], case.facets)
        idx = np.flatnonzero(traced)
        cos = case.normals[idx] @ d
        start = tnear(case, idx, cos, args.tnear_ulps)
        origins = np.ascontiguousarray(
            (case.centroids[idx] + start[:, None] * d[None, :]).astype(np.float32))
        direction = np.ascontiguousarray(d.astype(np.float32)[None, :])
        c0 = time.process_time()
        t0 = time.perf_counter()
        hit = scene.run(origins, direction, query="OCCLUDED")
        step_ms.append(1e3 * (time.perf_counter() - t0))
        cpu_s += time.process_time() - c0
        rays += idx.size
        e_blocked = hit == 0
        s_blocked = slim_blocked[idx]
        embree_shadowed += int(e_blocked.sum())
        slim_shadowed += int(s_blocked.sum())
        for k in np.flatnonzero(e_blocked != s_blocked):
            disagreements.append((s, int(idx[k]), bool(s_blocked[k]), bool(e_blocked[k]),
                                  float(cos[k])))
        # A few agreeing rays of each kind per step, for the referee check.
        for kind in (True, False):
            same = np.flatnonzero((e_blocked == s_blocked) & (s_blocked == kind))
            if same.size:
                agreements[kind].append((s, int(idx[same[same.size // 2]])))
    threads_after = os_threads()
    loop_s = sum(step_ms) / 1e3

    referee = Referee(case)
    settled = spread(disagreements, args.cap)
    settled.sort()
    rows = []
    slim_right = embree_right = 0
    marginal = 0
    for s, i, sb, eb, cos in settled:
        blocked, margin, t = referee.test(s, i)
        slim_right += sb == blocked
        embree_right += eb == blocked
        # Within 1e-6 of a triangle edge in barycentric terms: the f64 answer itself
        # hangs on rounding there.
        marginal += abs(margin) < 1e-6
        rows.append({"step": s, "facet": i, "cos": cos, "slim": int(sb), "embree": int(eb),
                     "referee": int(blocked), "margin": margin, "t_m": t})
    check = spread(agreements[True], args.check_agreements // 2) + spread(
        agreements[False], args.check_agreements - args.check_agreements // 2)
    check.sort()
    check_ok = 0
    for s, i in check:
        check_ok += referee.test(s, i)[0] == bool(unpack(case.shadowed[s], case.facets)[i])

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = out.with_name(out.stem + "_disagreements.csv")
    with open(csv_path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["step", "facet", "cos", "slim", "embree",
                                               "referee", "margin", "t_m"])
        writer.writeheader()
        writer.writerows(rows)

    slim_only = sum(1 for r in disagreements if r[2] and not r[3])
    summary = {
        **build,
        "facets": case.facets,
        "steps": case.steps,
        "tracing_threads": 1,
        "os_threads_after_tracing": threads_after,
        "tracing_cpu_over_wall": cpu_s / loop_s if loop_s > 0 else None,
        "tnear": f"max(slim t_min, min({args.tnear_ulps:g} * eps_f32 * R / cos, "
                 "longest edge)), "
                 f"R = {case.radius:.6g} m",
        "tnear_ulps": args.tnear_ulps,
        "body_radius_m": case.radius,
        "loop_s": loop_s,
        "ms_per_step_mean": 1e3 * loop_s / case.steps,
        "ms_per_step_min": min(step_ms),
        "rays": rays,
        "rays_per_s": rays / loop_s,
        "rays_match_slim": rays == case.slim["traced_facet_steps"],
        "shadowed_facet_steps": embree_shadowed,
        "slim_shadowed_facet_steps": slim_shadowed,
        "disagreements": len(disagreements),
        "slim_shadowed_embree_lit": slim_only,
        "embree_shadowed_slim_lit": len(disagreements) - slim_only,
        "refereed": len(settled),
        "referee_capped": len(settled) < len(disagreements),
        "slim_right": slim_right,
        "embree_right": embree_right,
        "marginal": marginal,
        "referee_check": {"rays": len(check), "agree": check_ok},
        "disagreements_csv": csv_path.name,
    }
    out.write_text(json.dumps(summary, indent=2) + "\n")
    print(f"embree: {summary['ms_per_step_mean']:.3f} ms/step (min"
          f" {summary['ms_per_step_min']:.3f}), {summary['rays_per_s']:.3e} rays/s,"
          f" {embree_shadowed} shadowed facet-steps (slim {slim_shadowed});"
          f" {len(disagreements)} disagreements, refereed {len(settled)}: slim right"
          f" {slim_right}, Embree right {embree_right}; referee check"
          f" {check_ok}/{len(check)}")
    del keep_alive, scene


if __name__ == "__main__":
    main()
