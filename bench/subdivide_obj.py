#!/usr/bin/env python3
"""Writes an OBJ mesh with every triangle split into four, LEVELS times (x4 facets per
level), midpoints shared between neighbours. Used by bench/shards.sh to make the 786k and
3.1M-facet Itokawa shapes from the shipped 49,152-facet model.

usage: bench/subdivide_obj.py IN.obj LEVELS OUT.obj
"""
import sys


def read_obj(path):
    vertices, faces = [], []
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p:
                continue
            if p[0] == "v":
                vertices.append(tuple(float(x) for x in p[1:4]))
            elif p[0] == "f":
                faces.append(tuple(int(x.split("/")[0]) - 1 for x in p[1:4]))
    return vertices, faces


def split(vertices, faces):
    midpoint = {}

    def mid(a, b):
        key = (a, b) if a < b else (b, a)
        if key not in midpoint:
            va, vb = vertices[a], vertices[b]
            vertices.append(tuple((x + y) / 2 for x, y in zip(va, vb)))
            midpoint[key] = len(vertices) - 1
        return midpoint[key]

    out = []
    for a, b, c in faces:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        out += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
    return out


def main():
    src, levels, dst = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    vertices, faces = read_obj(src)
    for _ in range(levels):
        faces = split(vertices, faces)
    with open(dst, "w") as f:
        f.writelines(f"v {x:.9f} {y:.9f} {z:.9f}\n" for x, y, z in vertices)
        f.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)


main()
