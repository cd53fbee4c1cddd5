"""sensor_msgs/PointCloud2 ↔ arrays: x, y, z, intensity and colour, in any field layout.

* Coordinates of any numeric type, in any order, any ``point_step``/``row_step`` (row padding is
  skipped), either endianness; an organised cloud (height > 1) is flattened row by row.
* Intensity: the field ``intensity`` (or ``intensities``, ``i``), any numeric type.
* Colour: the field ``rgb`` or ``rgba``, 4 bytes (FLOAT32 or UINT32) holding a packed
  0xAARRGGBB word as PCL writes it (``pcl::PointXYZRGB``): red in bits 16–23, green 8–15, blue
  0–7. The writer writes ``rgb`` as PCL does: a FLOAT32 field whose bits are the packed word.
* Invalid points (a non-finite coordinate or intensity; ``is_dense`` false) are removed and the
  cloud kept, with its colours and intensities aligned.
"""

from __future__ import annotations

import numpy as np

from semslam.mission.codec_base import MalformedMessage

_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
_INTENSITY_NAMES = ("intensity", "intensities", "i")
_RGB_NAMES = ("rgb", "rgba")
FLOAT32 = 7


def _field_dtype(f, endian: str, step: int) -> np.dtype:
    if f.datatype not in _POINTFIELD_DTYPES:
        raise MalformedMessage(f"fields.{f.name}", f"unknown PointField datatype {f.datatype}")
    fmt = np.dtype(endian + _POINTFIELD_DTYPES[f.datatype])
    if f.offset + fmt.itemsize > step:
        raise MalformedMessage(f"fields.{f.name}", f"offset {f.offset} beyond point_step {step}")
    return fmt


def _packed_bytes(msg) -> np.ndarray:
    """The cloud's points as one contiguous byte array of width·height·point_step bytes."""
    step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    n = width * height
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    row = width * step
    row_step = int(msg.row_step)
    if height > 1 and row_step > row:
        need = (height - 1) * row_step + row
        if data.size < need:
            raise MalformedMessage("data", f"{data.size} bytes, expected at least {need}")
        # Drop the padding at the end of each row: a strided view, then one contiguous copy.
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, row), strides=(row_step, 1), writeable=False)
        data = np.ascontiguousarray(rows).reshape(-1)
    elif data.size < n * step:
        raise MalformedMessage("data", f"{data.size} bytes, expected {n * step} ({n} points × {step})")
    return data[: n * step]


def _column(buf: np.ndarray, fmt: np.dtype, offset: int, step: int) -> np.ndarray:
    return buf.view(np.dtype({"names": ["v"], "formats": [fmt], "offsets": [offset], "itemsize": step}))["v"]


def decode_pointcloud2_arrays(msg) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """x, y, z (N×3 float32), intensity (N float32 or None) and colour (N×3 uint8 or None) of a
    PointCloud2, vectorised. Invalid (non-finite) points are kept here; the caller filters them."""
    fields = {f.name: f for f in msg.fields}
    for axis in "xyz":
        if axis not in fields:
            raise MalformedMessage("fields", f"no '{axis}' field (have {sorted(fields)})")
    iname = next((n for n in _INTENSITY_NAMES if n in fields), None)
    cname = next((n for n in _RGB_NAMES if n in fields), None)
    endian = ">" if msg.is_bigendian else "<"
    step = int(msg.point_step)
    xyz = [_field_dtype(fields[a], endian, step) for a in "xyz"]
    ifmt = _field_dtype(fields[iname], endian, step) if iname else None
    if cname:
        cfmt = _field_dtype(fields[cname], endian, step)
        if cfmt.itemsize != 4:
            raise MalformedMessage(
                f"fields.{cname}", f"a packed colour needs 4 bytes, datatype {fields[cname].datatype}"
            )
    n = int(msg.width) * int(msg.height)
    if n == 0:
        return (
            np.zeros((0, 3), np.float32),
            np.zeros(0, np.float32) if iname else None,
            np.zeros((0, 3), np.uint8) if cname else None,
        )
    buf = _packed_bytes(msg)
    offs = [fields[a].offset for a in "xyz"]
    if (
        all(fmt == np.dtype("<f4") for fmt in xyz)
        and offs[1] == offs[0] + 4
        and offs[2] == offs[0] + 8
        and step % 4 == 0
        and offs[0] % 4 == 0
    ):
        # Fast path (the common layout): float32 x, y, z adjacent → one strided view, one copy.
        words = buf.view("<f4").reshape(n, step // 4)
        points = np.array(words[:, offs[0] // 4 : offs[0] // 4 + 3], dtype=np.float32)
    else:
        points = np.empty((n, 3), np.float32)
        for k, (fmt, off) in enumerate(zip(xyz, offs)):
            points[:, k] = _column(buf, fmt, off, step)
    intensity = None if ifmt is None else _column(buf, ifmt, fields[iname].offset, step).astype(np.float32)
    rgb = None
    if cname:
        word = _column(buf, np.dtype(endian + "u4"), fields[cname].offset, step)
        rgb = np.stack([(word >> 16) & 0xFF, (word >> 8) & 0xFF, word & 0xFF], axis=1).astype(np.uint8)
    return points, intensity, rgb


def valid_points(
    points: np.ndarray, intensity: np.ndarray | None, rgb: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The points with finite coordinates (and intensity), colours and intensities kept aligned."""
    # Cheap whole-array test first; the per-point mask only for clouds that have invalid points.
    if np.isfinite(points.reshape(-1)).all() and (intensity is None or np.isfinite(intensity).all()):
        return points, intensity, rgb
    ok = np.isfinite(points).all(axis=1)
    if intensity is not None:
        ok &= np.isfinite(intensity)
    return (
        points[ok],
        None if intensity is None else intensity[ok],
        None if rgb is None else rgb[ok],
    )


def pointcloud2_fields(
    points: np.ndarray, intensity: np.ndarray | None, rgb: np.ndarray | None
) -> tuple[list[tuple[str, int]], int, np.ndarray]:
    """What a writer needs for an unorganised little-endian PointCloud2 of these arrays:
    [(field name, offset)] (all FLOAT32, 4 bytes), point_step, and the data bytes."""
    names = ["x", "y", "z"] + (["intensity"] if intensity is not None else []) + (["rgb"] if rgb is not None else [])
    formats = ["<f4"] * (len(names) - (rgb is not None)) + (["<u4"] if rgb is not None else [])
    rec = np.empty(len(points), dtype=np.dtype({"names": names, "formats": formats}))
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    if intensity is not None:
        rec["intensity"] = intensity
    if rgb is not None:
        c = rgb.astype(np.uint32)
        rec["rgb"] = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
    return [(name, 4 * k) for k, name in enumerate(names)], 4 * len(names), rec.view(np.uint8).reshape(-1)
