#!/usr/bin/env python3
"""Writes the binary seeds of the fuzz corpus (tests/fuzz.rs): PLY, STL, SPK, binary PCK,
FITS and PNG files of a few kB, each a small valid file of its kind. Deterministic: running
it again gives byte-identical files. Needs only Python's standard library.

    python3 tests/corpus/make_binary.py
"""

import os
import struct
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))

TETRA = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
TETRA_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def write(relative, data):
    with open(os.path.join(HERE, relative), "wb") as f:
        f.write(data)


# --- meshes -------------------------------------------------------------------------


def ply_binary(big):
    """A tetrahedron with float coordinates, a uchar/int index list, a normal per vertex,
    an extra list per face and an element the reader skips."""
    e = ">" if big else "<"
    head = (
        "ply\nformat binary_%s_endian 1.0\ncomment binary seed\n"
        "element vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
        "property double nx\n"
        "element face 4\nproperty list uchar int vertex_indices\n"
        "property list uint16 float texcoord\n"
        "element material 1\nproperty uchar red\nend_header\n" % ("big" if big else "little")
    ).encode()
    body = b"".join(struct.pack(e + "fffd", *v, 0.5) for v in TETRA)
    for f in TETRA_FACES:
        body += struct.pack(e + "B3i", 3, *f) + struct.pack(e + "H2f", 2, 0.25, 0.75)
    body += b"\x07"
    return head + body


def ply_binary_doubles():
    """Big-endian doubles and a quad given as a ushort-counted uint list."""
    head = (
        b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty double x\n"
        b"property double y\nproperty double z\nelement face 2\n"
        b"property list ushort uint vertex_index\nend_header\n"
    )
    body = b"".join(struct.pack(">3d", *v) for v in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    body += struct.pack(">H4I", 4, 0, 1, 2, 3) + struct.pack(">H3I", 3, 0, 2, 3)
    return head + body


def stl_binary():
    header = b"solid but binary: some writers start the header like this".ljust(80, b" ")
    facets = b""
    for f in TETRA_FACES:
        facets += struct.pack("<3f", 0, 0, 0)
        for i in f:
            facets += struct.pack("<3f", *TETRA[i])
        facets += b"\0\0"
    return header + struct.pack("<I", len(TETRA_FACES)) + facets


# --- DAF (SPK, binary PCK) ---------------------------------------------------------

RECORD = 1024
FTP = b"FTPSTR:\r:\n:\r\n:\r\x00:\x81:\x10\xce:ENDFTP"


def daf(idword, ni, segments, big=False):
    """A DAF with ND = 2: file record, one summary record, one name record, then the
    segments' doubles. `segments` holds (start_et, stop_et, ints without the two
    addresses, doubles, name)."""
    e = ">" if big else "<"
    nd = 2
    size = nd + (ni + 1) // 2
    address = 3 * RECORD // 8 + 1
    summaries, data = b"", []
    names = b""
    for start, stop, ints, doubles, name in segments:
        begin, end = address, address + len(doubles) - 1
        packed = struct.pack(e + "2d", start, stop) + struct.pack(e + "%di" % ni, *ints, begin, end)
        summaries += packed.ljust(8 * size, b"\0")
        names += name.encode().ljust(8 * size, b" ")
        data += doubles
        address = end + 1
    file_record = (
        idword.ljust(8).encode()
        + struct.pack(e + "2i", nd, ni)
        + b"slim fuzz corpus".ljust(60)
        + struct.pack(e + "3i", 2, 2, address)
        + (b"BIG-IEEE" if big else b"LTL-IEEE")
    )
    file_record = file_record.ljust(699, b"\0") + FTP
    summary = struct.pack(e + "3d", 0, 0, len(segments)) + summaries
    body = struct.pack(e + "%dd" % len(data), *data)
    out = file_record.ljust(RECORD, b"\0") + summary.ljust(RECORD, b"\0")
    out += names.ljust(RECORD, b" ") + body
    return out.ljust(-(-len(out) // RECORD) * RECORD, b"\0")


def chebyshev(components, degree=2, half=1e9):
    """Types 2 (3 components) and 3 (6): one record over [-half, half] and the directory."""
    coefficients = []
    for c in components:
        coefficients += list(c) + [0.0] * (degree + 1 - len(c))
    rsize = 2 + len(coefficients)
    return [0.0, half] + coefficients + [-half, 2 * half, float(rsize), 1.0]


def discrete(states, epochs, window):
    """Types 9 and 13: states, epochs (fewer than 100: no epoch directory), window or
    degree, count."""
    doubles = [x for s in states for x in s] + list(epochs)
    return doubles + [float(window), float(len(states))]


def spk(big=False):
    half = 1e9
    asteroid = chebyshev([(1.5e8, 0.0, 0.0), (0.0, 1e6, 0.0), (0.0, 0.0, 1e3)], 2, half)
    sun = chebyshev([(5e5,), (1e5, 10.0), (0.0,), (0.0,), (1e-3,), (0.0,)], 1, half)
    return daf(
        "DAF/SPK",
        6,
        [
            (-half, half, (2000433, 10, 1, 2), asteroid, "FUZZY type 2"),
            (-half, half, (10, 0, 1, 3), sun, "SUN type 3"),
        ],
        big,
    )


def spk_discrete():
    epochs = [-1e9, -5e8, 0.0, 5e8, 1e9]
    states = [(1.5e8 + k, 1e6 * k, 0.0, 1e-3, 2e-3, 0.0) for k in range(5)]
    moon = [(3.8e5, 1e3 * k, 0.0, 0.0, 1.0, 0.0) for k in range(5)]
    return daf(
        "DAF/SPK",
        6,
        [
            (epochs[0], epochs[-1], (2000433, 10, 1, 9), discrete(states, epochs, 3), "FUZZY type 9"),
            (epochs[0], epochs[-1], (301, 399, 1, 13), discrete(moon, epochs, 3), "MOON type 13"),
        ],
    )


def bpc(big=False):
    half = 1e9
    angles = chebyshev([(0.1, 0.01), (1.2,), (0.0, 6.3e-3 * half)], 1, half)
    return daf("DAF/PCK", 5, [(-half, half, (31006, 1, 2), angles, "MOON_PA_DE421 type 2")], big)


# --- images ------------------------------------------------------------------------

BLOCK = 2880


def card(text):
    return text.ljust(80).encode()


def fits(bitpix, width, height, pixels, extra, pad=True, naxis3=False):
    cards = [
        "SIMPLE  =                    T / conforms to FITS standard",
        "BITPIX  = %20d" % bitpix,
        "NAXIS   = %20d" % (3 if naxis3 else 2),
        "NAXIS1  = %20d / columns" % width,
        "NAXIS2  = %20d / rows" % height,
    ]
    if naxis3:
        cards.append("NAXIS3  =                    1")
    cards += extra + ["END"]
    header = b"".join(card(c) for c in cards)
    header = header.ljust(-(-len(header) // BLOCK) * BLOCK, b" ")
    code = {8: "B", 16: "h", 32: "i", -32: "f", -64: "d"}[bitpix]
    data = struct.pack(">%d%s" % (len(pixels), code), *pixels)
    if pad:
        data = data.ljust(-(-len(data) // BLOCK) * BLOCK, b"\0")
    return header + data


def png_chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png(width, height, depth, colour, rows, texts=(), palette=None):
    out = b"\x89PNG\r\n\x1a\n" + png_chunk(
        b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    )
    if palette:
        out += png_chunk(b"PLTE", palette)
    for key, value in texts:
        out += png_chunk(b"tEXt", key + b"\0" + value)
    raw = b"".join(b"\0" + row for row in rows)
    return out + png_chunk(b"IDAT", zlib.compress(raw, 9)) + png_chunk(b"IEND", b"")


def main():
    write("ply/tetra-le.ply", ply_binary(False))
    write("ply/tetra-be.ply", ply_binary(True))
    write("ply/quads-be-doubles.ply", ply_binary_doubles())
    write("stl/tetra-binary.stl", stl_binary())
    write("spk/tiny-le.bsp", spk(False))
    write("spk/tiny-be.bsp", spk(True))
    write("spk/discrete.bsp", spk_discrete())
    write("bpc/tiny.bpc", bpc(False))
    write("bpc/tiny-be.bpc", bpc(True))
    header = [
        "BUNIT   = 'W m-2 sr-1'         / radiance",
        "DATE-OBS= '2018-06-10T00:00:00' / epoch",
        "EXPTIME =             1.25D-01 / s",
        "COMMENT   written for the slim fuzz corpus / not a value",
        "HISTORY   by make_binary.py",
        "OBJECT  = 'it''s a test'",
    ]
    write("fits/float32.fits", fits(-32, 3, 2, [0.0, 1.5, -2.0, 3e38, 1e-38, 7.0], header))
    write(
        "fits/int16-bscale.fits",
        fits(16, 4, 2, [0, 1, -1, 32767, -32768, 5, 6, 7],
             ["BSCALE  =                  0.5", "BZERO   =                32768"], pad=False),
    )
    write("fits/float64-naxis3.fits", fits(-64, 2, 2, [1.0, 2.0, 3.0, 4.0], [], pad=False, naxis3=True))
    write("fits/uint8.fits", fits(8, 2, 3, [0, 1, 2, 253, 254, 255], ["BUNIT   = '1'"], pad=False))
    stretch = [(b"slim:stretch", b"linear 0e0 1.361e3"), (b"slim:unit", b"W m-2")]
    write("png/grey8-stretch.png", png(3, 2, 8, 0, [b"\x00\x80\xff", b"\x10\x20\x30"], stretch))
    write("png/grey16.png", png(2, 2, 16, 0, [b"\x00\x01\xff\xff", b"\x80\x00\x12\x34"]))
    write("png/rgba8.png", png(2, 1, 8, 6, [b"\xff\x00\x00\x80\x00\xff\x00\xff"]))
    write(
        "png/palette2.png",
        png(5, 2, 2, 3, [b"\x1b\x40", b"\xe4\x00"], [(b"Comment", b"two bits")],
            palette=b"\x00\x00\x00\x55\x55\x55\xaa\xaa\xaa\xff\xff\xff"),
    )


if __name__ == "__main__":
    main()
