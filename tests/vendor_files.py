"""Vendor AFM files written for the tests: Gwyddion ``.gwy`` (``gwyfile``), Asylum ``.ibw``
(``igorwriter``), Park Systems TIFF and JPK image scans (``tifffile``, the private tags laid out as
the readers' documentation — ``pspylib``, ``SurfaceTopography``, AFMReader — describes them), and
minimal binary Nanoscope and Nanonis ``.sxm`` files built from the formats' layouts (no maintained
writer exists for either)."""

import struct

import numpy as np
import tifffile


def _utf16(text: str, n: int) -> list[int]:
    codes = [ord(c) for c in text][:n]
    return codes + [0] * (n - len(codes))


def write_park(path, raw, *, name="Z Height", forward=True, up=True, size_um=(10.0, 5.0), rate_hz=0.5,
               gain=1e-3, scale=1.0, offset=0.0, unit="um"):
    """A Park Systems TIFF (header version 2) written with ``tifffile``: an 8-bit picture plus the PSIA
    private tags (50432 magic, 50433 version, 50434 data, 50435 header; the header's field layout as
    ``pspylib``'s ``TiffReader`` and ``SurfaceTopography``'s ``PSReader`` document it). ``raw``:
    (lines, pixels) int16, int32 or float32, bottom line first; heights are gain·(scale·raw + offset)."""
    lines, points = raw.shape
    code = {np.dtype("<i2"): 0, np.dtype("<i4"): 1, np.dtype("<f4"): 2}[raw.dtype]
    fields = [("<i", 0), ("<32H", *_utf16(name, 32)), ("<8H", *_utf16("Contact", 8)), ("<d", 0.0), ("<2i", 0, 0),
              ("<2i", points, lines), ("<d", 0.0), ("<i", 0), ("<d", 0.0), ("<3i", int(forward), int(up), 0),
              ("<6d", *size_um, 0.0, 0.0, rate_hz, 0.0), ("<8H", *_utf16("nN", 8)), ("<5d", 0.0, 0.0, gain, scale, offset),
              ("<8H", *_utf16(unit, 8)), ("<6i", 0, 0, 0, 0, 0, 0), ("<2d", 0.0, 0.0), ("<24H", *[0] * 24),
              ("<3i", code, 0, 0), ("<3d", 0.0, 0.0, 0.0), ("<16H", *_utf16("tip", 16)), ("<64x",)]
    header = b"".join(struct.pack(f[0], *f[1:]) for f in fields)
    data = np.ascontiguousarray(raw).tobytes()
    tags = [(50432, 4, 1, 0x0E031301, True), (50433, 4, 1, 0x1000002, True), (50434, 1, len(data), data, True),
            (50435, 1, len(header), header, True)]
    tifffile.imwrite(path, np.zeros(raw.shape, np.uint8), extratags=tags)
    return path


def _jpk_slot(k: int, name: str, unit: str, multiply: float, offset: float) -> list:
    base = 0x8090 + k * 0x30  # slot k's tag block (stride 0x30), as JPK's image spec and SurfaceTopography lay it out
    return [(base, "s", 0, name, True), (base + 0x01, "s", 0, "scaled" if k else "raw", True),
            (base + 0x02, "s", 0, "raw" if k else "none", True), (base + 0x10, "s", 0, name, True),
            (base + 0x11, "s", 0, name, True), (base + 0x12, "s", 0, unit, True),
            (base + 0x13, "s", 0, "LinearScaling", True), (base + 0x14, "d", 1, multiply, True),
            (base + 0x15, "d", 1, offset, True)]


def write_jpk(path, pages, *, size_m=(5e-6, 4e-6), rate_hz=1.0):
    """A JPK image scan written with ``tifffile``: a thumbnail page with the scan's tags, then one page per
    ``(fancy name, retrace, raw int32 (lines, pixels) first line scanned first, multiply, offset)``, its
    ``nominal`` slot in m. Both ``SurfaceTopography``'s ``JPKReader`` and AFMReader's ``load_jpk`` read
    this layout to the same heights (checked when the fixture was written)."""
    lines, points = pages[0][2].shape
    scan = [(0x8000, "s", 0, "1.0", True), (0x8003, "s", 0, "2024-01-01 10:00:00 UTC", True),
            (0x8042, "d", 1, size_m[0], True), (0x8043, "d", 1, size_m[1], True), (0x8044, "d", 1, 0.0, True),
            (0x8045, "H", 1, 0, True), (0x8046, "I", 1, points, True), (0x8047, "I", 1, lines, True),
            (0x8049, "d", 1, rate_hz, True)]
    with tifffile.TiffWriter(path) as tiff:
        tiff.write(np.zeros((16, 16), np.uint8), extratags=scan)
        for fancy, retrace, raw, multiply, offset in pages:
            tags = [(0x8050, "s", 0, fancy.split()[0].lower(), True), (0x8051, "H", 1, int(retrace), True),
                    (0x8052, "s", 0, fancy, True), (0x8080, "I", 1, 2, True), (0x8081, "s", 0, "nominal", True)]
            tiff.write(np.asarray(raw, np.int32), extratags=tags + _jpk_slot(0, "raw", "V", 1.0, 0.0)
                       + _jpk_slot(1, "nominal", "m", multiply, offset))
    return path


def write_gwy(path, fields, meta=None):
    """``fields``: (title, z, z_unit, xy_real, xy_unit) each, written with gwyfile; ``meta`` on every channel."""
    from gwyfile.objects import GwyContainer, GwyDataField, GwySIUnit

    container = GwyContainer()
    for i, (title, z, z_unit, real, xy_unit) in enumerate(fields):
        container[f"/{i}/data"] = GwyDataField(np.ascontiguousarray(z, dtype=np.float64), xreal=real, yreal=real,
                                               si_unit_xy=GwySIUnit(unitstr=xy_unit),
                                               si_unit_z=GwySIUnit(unitstr=z_unit))
        container[f"/{i}/data/title"] = title
        if meta:
            container[f"/{i}/meta"] = GwyContainer(meta)
    container.tofile(str(path))
    return path


def write_ibw(path, layers, note):
    """``layers``: {label: (lines, points) image}; Asylum's layout (points, lines, channels), igorwriter."""
    import igorwriter

    stack = np.stack([img.T for img in layers.values()], axis=2).astype(np.float32)
    wave = igorwriter.IgorWave(stack, name="scan0001")
    wave.set_dimscale("x", 0, 1e-8, "m")
    wave.set_dimscale("y", 0, 1e-8, "m")
    for k, label in enumerate(layers):
        wave.set_dimlabel(2, k, label)
    wave.set_note("\r".join(f"{k}: {v}" for k, v in note.items()) + "\r")
    wave.save(str(path))
    return path


def write_nanoscope(path, layers, *, size_um=5.0, rate_hz=1.0, frame="Up", zsens_nm_per_v=20.0, zscale_v=440.0,
                     bytes_per_pixel=2):
    """A minimal binary Nanoscope (v5) file: ``layers`` is [(name, "Trace"/"Retrace", int16 or int32 (lines,
    points))]; ``bytes_per_pixel`` 4 as newer Nanoscope versions store (the Z scale spans 2^32 LSB)."""
    lines, points = layers[0][2].shape
    offset = 8192
    head = ["\\*File list", "\\Version: 0x05120130", "\\Date: 10:00:00 AM Mon Jan 01 2024",
            "\\*Scanner list", f"\\@Sens. Zsens: V {zsens_nm_per_v} nm/V",
            "\\*Ciao scan list", f"\\Scan Size: {size_um} {size_um} ~m", f"\\Samps/line: {points}",
            f"\\Lines: {lines}", f"\\Scan Rate: {rate_hz}", f"\\Frame direction: {frame}"]
    for k, (name, direction, _) in enumerate(layers):
        lsb, size = zscale_v / 256**bytes_per_pixel, lines * points * bytes_per_pixel
        head += ["\\*Ciao image list", f"\\Data offset: {offset + k * size}",
                 f"\\Data length: {size}", f"\\Bytes/pixel: {bytes_per_pixel}", f"\\Samps/line: {points}",
                 f"\\Number of lines: {lines}", f"\\Scan Size: {size_um} {size_um} ~m", "\\Aspect Ratio: 1:1",
                 f"\\Line Direction: {direction}", f'\\@2:Image Data: S [{name}] "{name}"',
                 f"\\@2:Z scale: V [Sens. Zsens] ({lsb:.10f} V/LSB) {zscale_v:.4f} V",
                 f"\\@2:Z offset: V [Sens. Zsens] ({lsb:.10f} V/LSB) 0.0000 V"]
    header = ("\r\n".join(head + ["\\*File list end"]) + "\r\n").encode("latin-1")
    data = b"".join(np.asarray(img, dtype=f"<i{bytes_per_pixel}").tobytes() for _, _, img in layers)
    path.write_bytes(header + b"\x1a" * (offset - len(header)) + data)
    return path


def write_sxm(path, channels, *, range_m=(5e-6, 4e-6), scan_time_s=(0.5, 0.6), scan_dir="up", angle_deg=0.0,
              scanit_type="FLOAT MSBFIRST"):
    """A Nanonis ``.sxm`` file laid out as Gwyddion's ``nanonis`` module and ``pySPM`` read it: ``:TAG:``
    header lines, ``:SCANIT_END:``, the bytes 0x1a 0x04, then for each ``(name, unit, direction, images)``
    of ``channels`` (direction ``both``: images = [forward, backward as stored, right → left]) its
    (lines, pixels) images as 32-bit floats in the byte order ``scanit_type`` names."""
    lines, points = channels[0][3][0].shape
    head = [":NANONIS_VERSION:", "2", ":SCANIT_TYPE:", f"              {scanit_type}", ":REC_DATE:", " 01.01.2024",
            ":REC_TIME:", "10:00:00", ":SCAN_PIXELS:", f"       {points}       {lines}",
            ":SCAN_TIME:", "             {:.3E}             {:.3E}".format(*scan_time_s),
            ":SCAN_RANGE:", "           {:.6E}           {:.6E}".format(*range_m),
            ":SCAN_OFFSET:", "             0.000000E+0         0.000000E+0", ":SCAN_ANGLE:", f"            {angle_deg:.3E}",
            ":SCAN_DIR:", scan_dir, ":DATA_INFO:", "\tChannel\tName\tUnit\tDirection\tCalibration\tOffset"]
    head += [f"\t{14 + k}\t{name}\t{unit}\t{direction}\t1.000E+0\t0.000E+0" for k, (name, unit, direction, _) in enumerate(channels)]
    head += ["", ":SCANIT_END:", "", ""]
    order = ">f4" if scanit_type.endswith("MSBFIRST") else "<f4"
    data = b"".join(np.asarray(image, order).tobytes() for *_, images in channels for image in images)
    path.write_bytes("\n".join(head).encode("ascii") + b"\x1a\x04" + data)
    return path
