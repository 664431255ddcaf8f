#!/usr/bin/env python3
"""Seed corpora for the fuzz targets (scripts/fuzz.sh): small volumes in every format and variant
the readers accept, from a synthetic pattern and from 8x8x8 crops of the shared NRRD volumes
(ADAPTISO_DATA, default ../shared/data; skipped when absent), plus PLY meshes and viewer queries.
Standard library only. Usage: make_seeds.py OUT_DIR"""
import base64
import bz2
import gzip
import os
import re
import struct
import sys
import zlib

# NRRD type name, NIfTI datatype, MetaImage, VTK XML, VTK legacy, struct code
TYPES = {
    "uchar": (2, "MET_UCHAR", "UInt8", "unsigned_char", "B"),
    "short": (4, "MET_SHORT", "Int16", "short", "h"),
    "ushort": (512, "MET_USHORT", "UInt16", "unsigned_short", "H"),
    "float": (16, "MET_FLOAT", "Float32", "float", "f"),
}


class Vol:
    def __init__(self, dims, tname, values):
        self.dims, self.tname, self.values = dims, tname, values

    def raw(self, big=False):
        code = TYPES[self.tname][4]
        return struct.pack(("<" if not big else ">") + code * len(self.values), *self.values)


def pattern(tname):
    dims = (4, 3, 2)
    vals = [(i * 7 + 3) % 50 for i in range(24)]
    return Vol(dims, tname, [float(v) / 3 if tname == "float" else v for v in vals])


def nrrd_header(v, enc, extra="", endian="little"):
    return (f"NRRD0004\n# seed\ntype: {v.tname}\ndimension: 3\nsizes: {v.dims[0]} {v.dims[1]} {v.dims[2]}\n"
            f"endian: {endian}\nencoding: {enc}\n{extra}").encode()


def nrrd_seeds(v):
    raw = v.raw()
    text = " ".join(str(x) for x in v.values).encode()
    return {
        "raw": nrrd_header(v, "raw", "spacings: 1 1 2\n") + b"\n" + raw,
        "big": nrrd_header(v, "raw", endian="big") + b"\n" + v.raw(True),
        "gzip": nrrd_header(v, "gzip") + b"\n" + gzip.compress(raw),
        "bzip2": nrrd_header(v, "bzip2") + b"\n" + bz2.compress(raw),
        "ascii": nrrd_header(v, "ascii") + b"\n" + text,
        "hex": nrrd_header(v, "hex") + b"\n" + raw.hex().encode(),
        "space": nrrd_header(v, "raw", "space: left-posterior-superior\nspace directions: (0,2,0) (-3,0,0) (0,0,4)\n"
                                       "space origin: (1,2,3)\nkinds: domain domain domain\n") + b"\n" + raw,
        "skip": nrrd_header(v, "raw", "byte skip: 3\nline skip: 1\n") + b"\nline\nabc" + raw,
    }


def nhdr_seeds(v):
    raw = v.raw()
    half = len(raw) // 2
    return {
        "single": nrrd_header(v, "raw", "data file: data.raw\n") + b"\0" + raw,
        "gzip": nrrd_header(v, "gzip", "data file: data.raw.gz\n") + b"\0" + gzip.compress(raw),
        "list": nrrd_header(v, "raw", "data file: LIST\ns1.raw\ns2.raw\n") + b"\0" + raw[:half],
        "pattern": nrrd_header(v, "raw", "data file: s%d.raw 1 2 1\n") + b"\0" + raw[:half],
        "endskip": nrrd_header(v, "raw", "byte skip: -1\ndata file: data.raw\n") + b"\0" + b"xx" + raw,
    }


def nifti(v, version=1):
    dt = TYPES[v.tname][0]
    bitpix = {2: 8, 4: 16, 512: 16, 16: 32}[dt]
    dims = [3, *v.dims, 1, 1, 1, 1]
    if version == 1:
        h = struct.pack("<i", 348) + b"\0" * 36 + struct.pack("<8h", *dims) + b"\0" * 14
        h += struct.pack("<hhh", dt, bitpix, 0) + struct.pack("<8f", 1, 1, 1, 2, 1, 1, 1, 1)
        h += struct.pack("<f", 352) + struct.pack("<ff", 1, 0)
        h = h.ljust(344, b"\0") + b"n+1\0"
        return h + b"\0" * 4 + v.raw()
    h = struct.pack("<i", 540) + b"n+2\0\r\n\x1a\n" + struct.pack("<hh", dt, bitpix)
    h += struct.pack("<8q", *dims) + b"\0" * 24 + struct.pack("<8d", 1, 1, 1, 2, 1, 1, 1, 1)
    h += struct.pack("<q", 544) + struct.pack("<dd", 1, 0)
    h = h.ljust(540, b"\0")
    return h + b"\0" * 4 + v.raw()


def metaimage_seeds(v):
    met = TYPES[v.tname][1]
    head = (f"ObjectType = Image\nNDims = 3\nDimSize = {v.dims[0]} {v.dims[1]} {v.dims[2]}\nElementType = {met}\n"
            f"ElementSpacing = 1 1 2\nOffset = 0 0 0\nElementByteOrderMSB = False\n")
    raw = v.raw()
    z = zlib.compress(raw)
    half = len(raw) // 2
    return {
        "local": (head + "ElementDataFile = LOCAL\n").encode() + raw,
        "compressed": (head + f"CompressedData = True\nCompressedDataSize = {len(z)}\nElementDataFile = LOCAL\n").encode() + z,
        "detached": (head + "ElementDataFile = data.raw\n").encode() + b"\0" + raw,
        "list": (head + "ElementDataFile = LIST\ns1.raw\ns2.raw\n").encode() + b"\0" + raw[:half],
        "pattern": (head + "ElementDataFile = s%d.raw 1 2 1\n").encode() + b"\0" + raw[:half],
    }


def vti(v, attrs, array_attrs, body, appended=b""):
    x, y, z = v.dims
    ext = f"0 {x - 1} 0 {y - 1} 0 {z - 1}"
    return (f'<?xml version="1.0"?>\n<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian" {attrs}>\n'
            f'<ImageData WholeExtent="{ext}" Origin="0 0 0" Spacing="1 1 2">\n<Piece Extent="{ext}">\n'
            f'<PointData Scalars="s">\n<DataArray type="{TYPES[v.tname][2]}" Name="s" {array_attrs}>').encode() + body + \
        b"</DataArray>\n</PointData>\n</Piece>\n</ImageData>\n" + appended + b"</VTKFile>\n"


def vti_seeds(v):
    raw = v.raw()
    z = zlib.compress(raw)
    zh32 = struct.pack("<4I", 1, len(raw), len(raw), len(z))
    zh64 = struct.pack("<4Q", 1, len(raw), len(raw), len(z))
    return {
        "ascii": vti(v, "", 'format="ascii"', " ".join(str(x) for x in v.values).encode()),
        "binary": vti(v, 'header_type="UInt32"', 'format="binary"', base64.b64encode(struct.pack("<I", len(raw)) + raw)),
        "binaryz": vti(v, 'header_type="UInt32" compressor="vtkZLibDataCompressor"', 'format="binary"',
                       base64.b64encode(zh32) + base64.b64encode(z)),
        "appended": vti(v, 'header_type="UInt64"', 'format="appended" offset="0"', b"",
                        b'<AppendedData encoding="raw">\n_' + struct.pack("<Q", len(raw)) + raw + b"\n</AppendedData>\n"),
        "appendedz": vti(v, 'header_type="UInt64" compressor="vtkZLibDataCompressor"', 'format="appended" offset="0"', b"",
                         b'<AppendedData encoding="raw">\n_' + zh64 + z + b"\n</AppendedData>\n"),
    }


def vtk_seeds(v):
    head = (f"# vtk DataFile Version 3.0\nseed\n{{}}\nDATASET STRUCTURED_POINTS\nDIMENSIONS {v.dims[0]} {v.dims[1]} {v.dims[2]}\n"
            f"SPACING 1 1 2\nORIGIN 0 0 0\nPOINT_DATA {len(v.values)}\nSCALARS s {TYPES[v.tname][3]} 1\nLOOKUP_TABLE default\n")
    return {
        "ascii": head.format("ASCII").encode() + " ".join(str(x) for x in v.values).encode() + b"\n",
        "binary": head.format("BINARY").encode() + v.raw(True) + b"\n",
    }


def dicom_seed():
    """A minimal Part 10 file: explicit VR little endian, one 8x8 uint16 slice."""
    def el(group, element, vr, value):
        if vr in ("OB", "OW", "SQ", "UN", "UT"):
            return struct.pack("<HH2sHI", group, element, vr.encode(), 0, len(value)) + value
        return struct.pack("<HH2sH", group, element, vr.encode(), len(value)) + value

    def text(s):
        b = s.encode()
        return b + (b"\0" if len(b) % 2 else b"")

    meta_body = el(2, 1, "OB", b"\0\1") + el(2, 2, "UI", text("1.2.840.10008.5.1.4.1.1.4")) + \
        el(2, 3, "UI", text("1.2.3.4")) + el(2, 0x10, "UI", text("1.2.840.10008.1.2.1"))
    meta = el(2, 0, "UL", struct.pack("<I", len(meta_body))) + meta_body
    pixels = struct.pack("<64H", *[(i * 37) % 4096 for i in range(64)])
    ds = el(0x8, 0x60, "CS", text("MR")) + el(0x20, 0xE, "UI", text("1.2.3.5")) + \
        el(0x20, 0x32, "DS", text("0\\0\\0")) + el(0x20, 0x37, "DS", text("1\\0\\0\\0\\1\\0")) + \
        el(0x28, 0x2, "US", struct.pack("<H", 1)) + el(0x28, 0x4, "CS", text("MONOCHROME2")) + \
        el(0x28, 0x10, "US", struct.pack("<H", 8)) + el(0x28, 0x11, "US", struct.pack("<H", 8)) + \
        el(0x28, 0x30, "DS", text("1\\1")) + el(0x28, 0x100, "US", struct.pack("<H", 16)) + \
        el(0x28, 0x101, "US", struct.pack("<H", 12)) + el(0x28, 0x102, "US", struct.pack("<H", 11)) + \
        el(0x28, 0x103, "US", struct.pack("<H", 0)) + el(0x28, 0x1052, "DS", text("0")) + \
        el(0x28, 0x1053, "DS", text("1")) + el(0x7FE0, 0x10, "OW", pixels)
    return b"\0" * 128 + b"DICM" + meta + ds


def ply_seeds():
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    head = "ply\nformat {}\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\n" \
           "property list uchar int vertex_indices\nend_header\n"
    ascii = head.format("ascii 1.0").encode() + "".join(f"{x} {y} {z}\n" for x, y, z in verts).encode() + \
        "".join(f"3 {a} {b} {c}\n" for a, b, c in faces).encode()
    binary = head.format("binary_little_endian 1.0").encode() + b"".join(struct.pack("<3f", *p) for p in verts) + \
        b"".join(struct.pack("<B3i", 3, *f) for f in faces)
    return {"ascii": ascii, "binary": binary}


def read_nrrd_crop(path, n=8):
    """An n^3 crop from the middle of a shared NRRD volume (raw or gzip, attached or detached)."""
    data = open(path, "rb").read()
    head, _, rest = data.partition(b"\n\n")
    fields = dict((k.strip().lower(), val.strip()) for k, _, val in
                  (line.partition(":") for line in head.decode("latin1").splitlines()[1:] if ":" in line and not line.startswith("#")))
    tname = fields.get("type", "")
    tmap = {"short": "short", "int16": "short", "signed short": "short", "ushort": "ushort", "uint16": "ushort",
            "unsigned short": "ushort", "uchar": "uchar", "uint8": "uchar", "unsigned char": "uchar", "float": "float"}
    if tname not in tmap or fields.get("dimension") != "3":
        return None
    t = tmap[tname]
    dims = [int(x) for x in fields["sizes"].split()]
    if "data file" in fields:
        rest = open(os.path.join(os.path.dirname(path), fields["data file"]), "rb").read()
    if fields.get("encoding") == "gzip" or fields.get("encoding") == "gz":
        rest = gzip.decompress(rest)
    elif fields.get("encoding") != "raw":
        return None
    code = TYPES[t][4]
    size = struct.calcsize(code)
    big = fields.get("endian") == "big"
    o = [max(0, d // 2 - n // 2) for d in dims]
    c = [min(n, d) for d in dims]
    vals = []
    for k in range(c[2]):
        for j in range(c[1]):
            start = (((o[2] + k) * dims[1] + o[1] + j) * dims[0] + o[0]) * size
            vals += struct.unpack((">" if big else "<") + code * c[0], rest[start:start + c[0] * size])
    return Vol(tuple(c), t, list(vals))


def main():
    out = sys.argv[1]
    vols = [(f"pattern_{t}", pattern(t)) for t in TYPES]
    data = os.environ.get("ADAPTISO_DATA", os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    if os.path.isdir(data):
        for name in sorted(os.listdir(data)):
            if re.search(r"\.(nhdr|nrrd)$", name):
                try:
                    v = read_nrrd_crop(os.path.join(data, name))
                except (OSError, ValueError, KeyError, struct.error, EOFError):
                    v = None
                if v:
                    vols.append(("crop_" + name.split(".")[0], v))
    else:
        print(f"make_seeds: {data} not found; synthetic seeds only")
    seeds = {t: {} for t in ("nrrd", "nhdr", "nifti", "nifti_gz", "metaimage", "vti", "vtk", "dicom", "raw", "ply", "request")}
    for name, v in vols:
        for k, b in nrrd_seeds(v).items():
            seeds["nrrd"][f"{name}_{k}"] = b
        for k, b in nhdr_seeds(v).items():
            seeds["nhdr"][f"{name}_{k}"] = b
        for ver in (1, 2):
            seeds["nifti"][f"{name}_v{ver}"] = nifti(v, ver)
            seeds["nifti_gz"][f"{name}_v{ver}_plain"] = b"\0" + nifti(v, ver)
            seeds["nifti_gz"][f"{name}_v{ver}_stream"] = b"\1" + gzip.compress(nifti(v, ver))
        for k, b in metaimage_seeds(v).items():
            seeds["metaimage"][f"{name}_{k}"] = b
        for k, b in vti_seeds(v).items():
            seeds["vti"][f"{name}_{k}"] = b
        for k, b in vtk_seeds(v).items():
            seeds["vtk"][f"{name}_{k}"] = b
        tcode = {"uchar": 0, "ushort": 2, "short": 3, "float": 6}[v.tname]
        seeds["raw"][name] = bytes([v.dims[0], v.dims[1], v.dims[2], tcode, 0, 0, 0, 0]) + v.raw()
    seeds["dicom"]["minimal"] = dicom_seed()
    seeds["ply"].update(ply_seeds())
    for i, q in enumerate(["iso=500", "iso=0.5&error=3&budget=150000&format=compact&client=tab-1",
                           "iso=1e-320&simplify=0.5&format=glb", "iso=nan&error=-1&client=%00", "iso=1&iso=2&format=ply"]):
        seeds["request"][f"q{i}"] = q.encode()
    for target, files in seeds.items():
        os.makedirs(os.path.join(out, target), exist_ok=True)
        for name, b in files.items():
            with open(os.path.join(out, target, name), "wb") as f:
                f.write(b)
    print(f"make_seeds: {sum(len(f) for f in seeds.values())} seeds from {len(vols)} volumes in {out}")


if __name__ == "__main__":
    main()
