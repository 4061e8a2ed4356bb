"""C3D trials: read with ezc3d after checking the header and parameter section, written with ezc3d
(gaps the standard way).  What the reader accepts: see calibrate.io.trial."""

from __future__ import annotations

import io
import math
import os
import shutil
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import ezc3d
import numpy as np

from calibrate.errors import TrialError
from calibrate.io.measurements import c3d_processing, measurements_from_c3d
from calibrate.io.trial import (
    UNITS_TO_METRES,
    Trial,
    check_input_file,
    fail,
    file_labels,
    one_line,
    output_target,
    parse_units,
    write_staged,
)
from calibrate.io.vicon import is_model_output, output_factor

#: Each kind of model output: the POINT parameter in which Vicon lists its labels, the parameter naming its unit,
#: and the unit write_c3d stores it in (Vicon's: angles in degrees, moments in N mm; points in the file's length
#: unit).
_C3D_KIND_GROUPS: dict[str, tuple[str, str, str]] = {
    "angle": ("ANGLES", "ANGLE_UNITS", "deg"),
    "force": ("FORCES", "FORCE_UNITS", "N"),
    "moment": ("MOMENTS", "MOMENT_UNITS", "Nmm"),
    "power": ("POWERS", "POWER_UNITS", "W"),
    "scalar": ("SCALARS", "", ""),
    "reaction": ("REACTIONS", "", ""),
    "point": ("MODELED_MARKERS", "", ""),
}
#: POINT parameters in which Vicon lists its model outputs, with the kind of quantity.
_C3D_OUTPUT_GROUPS: dict[str, str] = {group: kind for kind, (group, _, _) in _C3D_KIND_GROUPS.items()}


C3D_MAX_FRAMES = 65535  # the C3D header stores frame numbers as 16-bit words: the longest trial written here


class _BadC3D(ValueError):
    """Internal: a structural problem found in a C3D file before ezc3d reads it."""


def _c3d_float(raw: bytes, processor: int) -> float:
    """One 4-byte float in the file's processor format (84 Intel, 85 DEC, 86 MIPS)."""
    if processor == 86:
        return struct.unpack(">f", raw)[0]
    if processor == 85:  # DEC F-float: swap the 16-bit words, read as IEEE, divide by 4
        return struct.unpack("<f", raw[2:4] + raw[0:2])[0] / 4.0
    return struct.unpack("<f", raw)[0]


@dataclass(frozen=True)
class _Record:
    """One group or parameter record of a C3D parameter section, by its byte offsets in the section."""

    group_id: int  # negative: a group (its id negated); positive: a parameter of that group
    name: str
    kind: int  # a parameter's type (-1 char, 1 byte, 2 integer, 4 float); 0 for a group
    dims: tuple[int, ...]
    raw: bytes  # a parameter's data
    start: int  # the record's first byte (its name's length)
    link: int  # the offset to the next record from the link's own first byte, as it leads (0: the last)
    body: int  # after the link: a parameter's type byte, a group's description length
    end: int  # the description's length byte (after a parameter's data)
    described: bool = True  # False: the writer left the description's length byte out (the link leads to `end`)


def _c3d_records(section: bytes, processor: int) -> list[_Record]:
    """Walk the records of a C3D parameter section, in order.

    Raises _BadC3D when a record does not fit the section or names an unknown type: ezc3d can crash the
    interpreter on such files.
    """
    endian = ">" if processor == 86 else "<"
    end = len(section)
    pos = 4
    records: list[_Record] = []
    while pos + 2 <= end:
        n_chars = struct.unpack("b", section[pos : pos + 1])[0]
        if n_chars == 0:
            break
        group_id = struct.unpack("b", section[pos + 1 : pos + 2])[0]
        name_end = pos + 2 + abs(n_chars)
        if group_id == 0 or name_end + 2 > end:
            raise _BadC3D("a parameter record is broken")
        name = section[pos + 2 : name_end].decode("latin-1")
        if not name.isprintable() or not name.strip():
            raise _BadC3D("a parameter name is not text")
        link = struct.unpack(endian + "h", section[name_end : name_end + 2])[0]
        body = name_end + 2
        kind, dims, raw = 0, (), b""
        if group_id < 0:
            data_end = body
        else:
            if body + 2 > end:
                raise _BadC3D(f"parameter {name} is cut short")
            kind = struct.unpack("b", section[body : body + 1])[0]
            n_dims = section[body + 1]
            if kind not in (-1, 1, 2, 4) or n_dims > 7:
                raise _BadC3D(f"parameter {name} has an unknown type or shape")
            dims = tuple(section[body + 2 : body + 2 + n_dims])
            data_start = body + 2 + n_dims
            data_end = data_start + int(np.prod(dims, dtype=np.int64)) * abs(kind)
            raw = section[data_start:data_end]
        following = name_end + link
        # A link that leads to where the description's length byte belongs: the writer left the byte out
        # (OptiTrack Arena's mocap36.c3d, after POINT:LABELS; BTK reads on by the link), read as no description.
        described = not (link > 0 and following == data_end)
        if described and data_end + 1 > end:
            raise _BadC3D(f"parameter {name} runs past the parameter section")
        record_end = data_end + 1 + section[data_end] if described else data_end  # after the description
        if record_end > end:
            raise _BadC3D(f"the description of {name} runs past the parameter section")
        if link != 0 and endian == ">" and (link < 0 or following < record_end or following > end):
            # c3d.org's SGI samples (sample02) carry one link in Intel order, which leads where the record ends
            swapped = struct.unpack("<h", section[name_end : name_end + 2])[0]
            if record_end <= name_end + swapped <= end:
                link, following = swapped, name_end + swapped
        records.append(_Record(group_id, name.strip().upper(), kind, dims, raw, pos, link, body, data_end, described))
        if link == 0:
            break
        if link < 0 or following < record_end or following > end:
            raise _BadC3D(f"the link after {name} does not lead to the next parameter")
        pos = following
    return records


def _c3d_parameter_section(records: list[_Record]) -> dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]]:
    """Map (GROUP, NAME) of a C3D parameter section's parameters (its _c3d_records) to (type, dimensions, raw data).
    A parameter of no group is left out."""
    groups = {-r.group_id: r.name for r in records if r.group_id < 0}
    # A parameter of no group (c3d.org's Vicon force-plate samples: IS_STATIC) is no marker's: ezc3d files it
    # under a nameless group and reads on.
    return {(groups[r.group_id], r.name): (r.kind, r.dims, r.raw) for r in records
            if r.group_id > 0 and r.group_id in groups}


C3D_MAX_DESCRIPTION = 127  # characters of a description ezc3d reads: it takes the length byte as signed
EZC3D_GROUPS = ("POINT", "ANALOG", "FORCE_PLATFORM")  # the groups whose parameters ezc3d reads the data by, by name


def _section_for_ezc3d(section: bytes, records: list[_Record], processor: int, no_analog: bool = False
                       ) -> bytes | None:
    """The parameter section (its _c3d_records `records`) as ezc3d can read it, or None if it can read it as it is:
    the names of EZC3D_GROUPS and their parameters in capitals, every description cut to C3D_MAX_DESCRIPTION
    characters and the links after them shortened to match (the section zero-padded to its length).
    - ezc3d reads a description's length byte as signed: one of 128-255 characters (a KINARM robot's
      EXPERIMENT:SESSION, 163) became a request for 4 GB, three times, before it failed.
    - ezc3d looks its parameters up by their exact spelling, while a C3D's names are read regardless of case (the
      reader here does): an `ANALOG:Offset` beside analog channels made it fill in an empty OFFSET and crash the
      interpreter reading the analog data.  Only the groups it reads the data by: other groups' names are left as
      written (Vicon's PROCESSING:Bodymass, which calibrate.io.measurements reads by that name).
    - ezc3d refuses ANALOG:OFFSET stored as floats ("OFFSET parameter is not an INT": c3d.org's sample13, Dance.c3d
      and golfswing.c3d); they are written as the 16-bit integers the standard says, rounded.
    - ezc3d crashes the interpreter on a text parameter of no dimensions (a scalar: one character, as the standard
      reads it and the walk here does; found by fuzzing); it is written with one dimension of 1.
    - A description whose length byte the writer left out (`_Record.described`) is written with a length of 0.
    - `no_analog`: ANALOG:USED written as 0, for a file whose ANALOG:SCALE or OFFSET does not cover its channels
      (ezc3d crashes the interpreter on it: c3d.org's sample06, whose offsets are ANALOG:OFFSETS); its points are
      then read here, by the header's layout (_C3DLayout.own_points)."""
    groups = {-r.group_id: r.name for r in records if r.group_id < 0}  # (read in capitals)
    endian = ">" if processor == 86 else "<"

    def name(r: _Record) -> bytes:
        raw = section[r.start + 2 : r.body - 2]
        return raw.upper() if groups.get(abs(r.group_id)) in EZC3D_GROUPS else raw

    def float_offsets(r: _Record) -> bool:
        return groups.get(r.group_id) == "ANALOG" and r.name.startswith("OFFSET") and r.kind == 4

    def scalar_text(r: _Record) -> bool:
        return r.kind == -1 and not r.dims

    def analog_used(r: _Record) -> bool:
        return no_analog and groups.get(r.group_id) == "ANALOG" and r.name == "USED"

    def body(r: _Record) -> bytes:
        if scalar_text(r):
            return struct.pack("b", -1) + bytes([1, 1]) + r.raw
        if analog_used(r):
            return section[r.body : r.body + 2 + len(r.dims)] + bytes(len(r.raw))
        if not float_offsets(r):
            return section[r.body : r.end]
        values = [_c3d_float(r.raw[k : k + 4], processor) for k in range(0, len(r.raw), 4)]
        ints = np.clip(np.round(np.nan_to_num(values)), -32768, 32767).astype(endian + "i2").tobytes()
        return struct.pack("b", 2) + section[r.body + 1 : r.body + 2 + len(r.dims)] + ints

    if all(r.described and section[r.end] <= C3D_MAX_DESCRIPTION and name(r) == section[r.start + 2 : r.body - 2]
           and not float_offsets(r) and not scalar_text(r) and not analog_used(r) for r in records):
        return None
    out = bytearray(section[:4])
    for r in records:
        n = min(section[r.end], C3D_MAX_DESCRIPTION) if r.described else 0
        rest = body(r) + bytes([n]) + section[r.end + 1 : r.end + 1 + n]
        out += section[r.start : r.start + 2] + name(r)
        out += struct.pack(endian + "h", len(rest) + 2 if r.link else 0) + rest
    if len(out) > len(section):  # descriptions' length bytes put back where the blocks have no room for them
        raise _BadC3D("its descriptions' length bytes are missing and its blocks have no room for them")
    return bytes(out.ljust(len(section), b"\x00"))


def _mips_as_intel(data: bytes) -> bytes:
    """A big-endian MIPS (SGI, processor 86) C3D file's bytes as the Intel (84) file ezc3d reads: every 16-bit word
    and float of the header, the parameter section and the data section in little-endian order, the processor byte
    84.  Characters and bytes (labels, units, a parameter's dimensions, the event flags) stay as written.

    The header: words 2-6 (counts, frames), 7-8 (POINT:SCALE, float), 9-10 (data block, analog words per frame),
    11-12 (rate, float), 13-152 (reserved words, the event key and count), 153-188 (18 event times, floats); its
    event labels and flags are bytes.  Each parameter record: its link word, and its data when it is 16-bit
    integers or floats.  The data section: every word, 4 bytes (float storage, POINT:SCALE < 0) or 2 (integer), to
    the end of the file.  Raises _BadC3D where the parameter section does not walk (_c3d_records; a link written in
    Intel order, as in c3d.org's SGI samples, is read as it leads)."""
    if len(data) < 512:
        raise _BadC3D("shorter than a C3D header")
    out = bytearray(data)

    def swap(start: int, stop: int, width: int) -> None:
        stop = start + (max(min(stop, len(data)) - start, 0) // width) * width
        if stop <= start:  # nothing there (a data block past the file's end: the layout check says so)
            return
        out[start:stop] = np.frombuffer(data, dtype=f">u{width}", count=(stop - start) // width,
                                        offset=start).astype(f"<u{width}").tobytes()

    for start, stop, width in ((2, 12, 2), (12, 16, 4), (16, 20, 2), (20, 24, 4), (24, 304, 2), (304, 376, 4)):
        swap(start, stop, width)
    param_start = (data[0] - 1) * 512
    data_block = struct.unpack(">H", data[16:18])[0]
    if param_start + 4 > len(data):
        raise _BadC3D("its parameter section is missing")
    n_blocks = data[param_start + 2]
    if data[0] + n_blocks < data_block:  # a count short or 0: the section runs to the data (_check_c3d_layout)
        n_blocks = data_block - data[0]
    section = data[param_start : param_start + 512 * n_blocks]
    for r in _c3d_records(section, 86):
        out[param_start + r.body - 2 : param_start + r.body] = struct.pack("<h", r.link)  # to the next record
        if r.group_id > 0 and r.kind in (2, 4):
            first = param_start + r.body + 2 + len(r.dims)
            swap(first, first + len(r.raw), r.kind)
    out[param_start + 3] = 84
    if data_block >= 1:
        swap((data_block - 1) * 512, len(data), 4 if struct.unpack(">f", data[12:16])[0] < 0 else 2)
    return bytes(out)


_Table = dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]]  # (group, name) -> (type, dims, bytes)


def _c3d_first(table: _Table, key: tuple[str, str], processor: int, signed: bool) -> float | None:
    """First value of a float, 16-bit integer (signed or not) or byte parameter, or None."""
    if key not in table:
        return None
    kind, _, raw = table[key]
    if kind == 4 and len(raw) >= 4:
        value = _c3d_float(raw[:4], processor)
        return float(value) if np.isfinite(value) else None
    if kind == 2 and len(raw) >= 2:
        return float(struct.unpack((">" if processor == 86 else "<") + ("h" if signed else "H"), raw[:2])[0])
    if kind == 1 and raw:
        return float(raw[0])
    return None


def _c3d_integer(table: _Table, key: tuple[str, str], processor: int) -> int | None:
    """First value of an integer or float parameter read as a whole number (16-bit integers unsigned), or None."""
    value = _c3d_first(table, key, processor, signed=False)
    return None if value is None else int(value)


def _c3d_number(table: _Table, key: tuple[str, str], processor: int) -> float | None:
    """First value of a float or integer parameter (integers signed, as C3D stores them), or None."""
    return _c3d_first(table, key, processor, signed=True)


def _c3d_long_field(table: _Table, key: tuple[str, str], processor: int) -> int | None:
    """A TRIAL:ACTUAL_*_FIELD frame number: two unsigned 16-bit words, low word first; None when absent."""
    if key not in table:
        return None
    kind, _, raw = table[key]
    if kind == 2 and len(raw) >= 4:
        low, high = struct.unpack((">" if processor == 86 else "<") + "2H", raw[:4])
        return low + (high << 16)
    if kind == 4 and len(raw) >= 8:  # some writers store the two words as floats
        low, high = _c3d_float(raw[:4], processor), _c3d_float(raw[4:8], processor)
        if np.isfinite(low) and np.isfinite(high) and low >= 0 and high >= 0:
            return int(low) + (int(high) << 16)
    return None


@dataclass(frozen=True)
class _C3DLayout:
    """What the reader needs from a C3D file's header and parameters besides what ezc3d gives."""

    frames: int | None  # frames of a trial too long for the header; None: ezc3d's count is used as is
    first_frame: int | None  # 0-based first frame from TRIAL:ACTUAL_START_FIELD past the header's 65535, else None
    #: The point data read here, not by ezc3d, as the header lays them out: (offset in bytes, points, frames, words
    #: per frame, float storage, POINT:SCALE, processor), where the ANALOG parameters give another number of analog
    #: words per frame than the header (BTS's files, c3d.org sample28: ANALOG:USED 0 beside 6 analog words a frame),
    #: by which ezc3d would read every frame but the first from the wrong place; None: ezc3d's points are used.
    own_points: tuple[int, int, int, int, bool, float, int] | None = None
    #: (offset in bytes, bytes) of a parameter section for ezc3d to read in place of the file's (_section_for_ezc3d);
    #: None: the file is read as it is.
    section: tuple[int, bytes] | None = None
    #: The whole file as an Intel C3D, read in place of the file: a big-endian MIPS (SGI) file, whose data ezc3d
    #: cannot read (_mips_as_intel); None: the file as it is.
    intel: bytes | None = None


def _check_c3d_layout(path: Path, size: int) -> _C3DLayout:
    """Check a C3D file's header and parameter section against its size before ezc3d reads it.

    ezc3d can crash the interpreter on a file cut or damaged inside its parameter
    section, and silently drops frames from a file cut inside its data; both are caught here.
    Returns the frame count and first frame the file gives for trials too long for the header.
    """
    redo = "export it again from your capture software"

    def bad(reason: str) -> TrialError:
        return fail(path, f"not a readable C3D file ({reason})", redo)

    if size < 512:
        raise bad(f"only {size} bytes, shorter than a C3D header")
    with open(path, "rb") as fh:
        header = fh.read(512)
        if header[0] == 0:  # some writers pad the start with zeros; ezc3d skips them
            return _C3DLayout(frames=None, first_frame=None)
        if header[1] != 0x50 or header[0] < 2:
            raise bad("no C3D signature in its header")
        param_start = (header[0] - 1) * 512
        fh.seek(param_start)
        head = fh.read(4)
        if len(head) < 4:
            raise bad("truncated: its parameter section is missing")
        n_blocks, processor = head[2], head[3]
        if processor not in (84, 85, 86):
            raise bad(f"unknown processor type {processor} in its parameter section")
        intel = None
        if processor == 86:  # big-endian (SGI): read as the Intel file it converts to, which ezc3d reads
            fh.seek(0)
            try:
                intel = _mips_as_intel(fh.read())
            except _BadC3D as exc:
                raise bad(f"damaged parameter section: {exc}") from None
            fh, header, processor = io.BytesIO(intel), intel[:512], 84
        # The section runs to the data section where the header's count of its blocks is short or 0 (c3d.org's
        # sample15 says 3 blocks where its parameters fill 5, PhaseSpace's says 0): ezc3d reads on to the last
        # parameter's link as well.
        data_block = struct.unpack("<H", header[16:18])[0]
        if header[0] + n_blocks < data_block and param_start + 512 * (data_block - header[0]) <= size:
            n_blocks = data_block - header[0]
        if n_blocks == 0 or param_start + 512 * n_blocks > size:
            raise bad("truncated inside its parameter section")
        fh.seek(param_start)
        section = fh.read(512 * n_blocks)
        fh.seek(max(size - 512, 0))
        tail = fh.read(512)
    try:
        records = _c3d_records(section, processor)
        table = _c3d_parameter_section(records)
    except _BadC3D as exc:
        raise bad(f"damaged parameter section: {exc}") from None

    endian = "<"  # Intel and DEC store integers little-endian
    n_points, n_analog, first, last = struct.unpack(endian + "4H", header[2:10])
    data_block = struct.unpack(endian + "H", header[16:18])[0]
    is_float = _c3d_float(header[12:16], processor) < 0
    used = _c3d_integer(table, ("POINT", "USED"), processor)
    if used is None and n_points and not any(g == "POINT" for g, _ in table):
        # PhaseSpace's sample (c3d.org sample20): 40 points in its header, no POINT group, so no labels
        raise fail(path, f"C3D file's header lists {n_points} points but its parameter section has no POINT group "
                         "(no labels, no scale)", "export it again with its parameters, or as a TRC file")
    if used is not None and used != n_points:
        raise bad(f"its header lists {n_points} points but POINT:USED says {used}")
    point_scale = _c3d_number(table, ("POINT", "SCALE"), processor)
    if n_points and point_scale is not None:  # ezc3d reads the points by POINT:SCALE, the size check by the header
        if point_scale == 0:
            raise bad("POINT:SCALE is 0, which would make every coordinate 0")
        if (point_scale < 0) != is_float:
            raise bad(
                f"its header says {'float' if is_float else 'integer'} storage but POINT:SCALE "
                f"({point_scale:g}) says {'float' if point_scale < 0 else 'integer'}"
            )
        header_scale = _c3d_float(header[12:16], processor)
        if not is_float and header_scale > 0 and not math.isclose(point_scale, header_scale, rel_tol=1e-6):
            # Integers times the scale are the positions: c3d.org's sample06 (an adult's walk, 1.23 m/s at 114
            # steps a minute by its header's 0.0551) would read 2.56 times smaller, a toddler's, by its 0.0215.  A
            # header scale of 0 gives no scale of its own (POINT:SCALE is read, as before).
            raise fail(path, f"C3D file's header and POINT:SCALE give its integer coordinates different scales "
                             f"({header_scale:g} and {point_scale:g}: positions {header_scale / point_scale:.3g} "
                             "times apart)", "correct the wrong one (e.g. in Mokka) or export the trial again")
    analog_per_frame = struct.unpack(endian + "H", header[18:20])[0]
    n_channels = max(
        n_analog // analog_per_frame if analog_per_frame else 0,
        _c3d_integer(table, ("ANALOG", "USED"), processor) or 0,
    )
    # ezc3d crashes when these are shorter than the channel list: its analog channels are then kept from it
    uncovered = [name for name in ("SCALE", "OFFSET") if n_channels and int(np.prod(
        table.get(("ANALOG", name), (0, (0,), b""))[1], dtype=np.int64)) < n_channels]
    try:
        for_ezc3d = _section_for_ezc3d(section, records, processor, no_analog=bool(uncovered))
    except _BadC3D as exc:
        raise bad(f"damaged parameter section: {exc}") from None
    if data_block == 0 or (data_block - 1) * 512 > size:
        raise bad("truncated before its data section")

    frame_bytes = (4 * n_points + n_analog) * (4 if is_float else 2)
    data_start = (data_block - 1) * 512
    start_field = _c3d_long_field(table, ("TRIAL", "ACTUAL_START_FIELD"), processor)
    end_field = _c3d_long_field(table, ("TRIAL", "ACTUAL_END_FIELD"), processor)
    long_frames = _c3d_number(table, ("POINT", "LONG_FRAMES"), processor)
    n_frames: int | None = _c3d_integer(table, ("POINT", "FRAMES"), processor)
    long_count: int | None = None  # the count of a trial that may be longer than the header can say
    if (last == 0xFFFF or n_frames == 0xFFFF) and frame_bytes:
        if long_frames is not None and long_frames >= 1:
            long_count = int(long_frames)
        elif start_field and end_field and end_field >= start_field:
            long_count = end_field - start_field + 1
    if long_count is None and (n_frames is None or n_frames == 0xFFFF) and last == 0xFFFF and frame_bytes:
        # The header is capped at 65535 and nothing else gives the count: as many frames as
        # the data section holds, less the zero bytes that pad its last 512-byte block.
        held = max(size - data_start, 0)
        zeros = min(len(tail) - len(tail.rstrip(b"\x00")), 511, held)
        long_count = min(-(-(held - zeros) // frame_bytes), held // frame_bytes)
    if long_count is not None:
        n_frames = long_count
    elif n_frames is None or n_frames == 0xFFFF:  # no count, or a long trial counted elsewhere
        n_frames = last - first + 1 if first >= 1 and last >= first else 0
    counted = last - first + 1 if 1 <= first <= last < 0xFFFF else None  # the header's own count
    if (long_count is None and counted is not None and frame_bytes and n_frames > counted
            and data_start + counted * frame_bytes <= size < data_start + n_frames * frame_bytes):
        n_frames = counted  # POINT:FRAMES one past the header and the data (c3d.org's sample13: 515, 514 and 514)
    if frame_bytes and data_start + n_frames * frame_bytes > size:
        held = max(size - data_start, 0) // frame_bytes
        raise fail(
            path,
            f"C3D file is truncated: it should hold {n_frames} frames but holds only {held}",
            redo,
        )
    first_frame = start_field - 1 if start_field and first == 0xFFFF else None  # past what the header holds
    own = None
    if uncovered and frame_bytes and long_count is not None:
        raise bad(f"ANALOG:{uncovered[0]} does not cover its {n_channels} analog channels")
    if uncovered and frame_bytes:  # ezc3d told of no analog channels: the points read here, as the header lays them out
        scale = point_scale if point_scale is not None else _c3d_float(header[12:16], processor)
        own = (data_start, n_points, n_frames, 4 * n_points + n_analog, is_float, scale, processor)
    elif n_analog and frame_bytes and long_count is None:
        # ezc3d takes the analog words of a frame from ANALOG:USED and ANALOG:RATE / POINT:RATE, the header from its
        # own words 3 and 10; where they disagree ezc3d strides through the data by the parameters.
        point_rate = _c3d_number(table, ("POINT", "RATE"), processor) or _c3d_float(header[20:24], processor)
        analog_rate = _c3d_number(table, ("ANALOG", "RATE"), processor) or 0.0
        used_analog = _c3d_integer(table, ("ANALOG", "USED"), processor) or 0
        per_frame = int(round(analog_rate / point_rate)) if point_rate and analog_rate > 0 else 0
        if used_analog * per_frame != n_analog:
            scale = point_scale if point_scale is not None else _c3d_float(header[12:16], processor)
            own = (data_start, n_points, n_frames, 4 * n_points + n_analog, is_float, scale, processor)
    return _C3DLayout(frames=long_count if frame_bytes else None, first_frame=first_frame, own_points=own,
                      section=None if for_ezc3d is None else (param_start, for_ezc3d), intel=intel)


def _read_points(path: Path | bytes, layout: tuple[int, int, int, int, bool, float, int]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The point words of a C3D file (or its bytes) read as its header lays them out: (4, points, frames) with
    coordinates in file units (integer storage times POINT:SCALE), and the residual words (1, points, frames),
    negative where invalid."""
    start, n_points, n_frames, words, is_float, scale, processor = layout
    width = 4 if is_float else 2
    if isinstance(path, bytes):
        raw = np.frombuffer(path, dtype=np.uint8, count=n_frames * words * width, offset=start)
    else:
        raw = np.fromfile(path, dtype=np.uint8, count=n_frames * words * width, offset=start)
    if is_float:
        if processor == 85:  # DEC: the 16-bit halves swapped, the value 4 times the IEEE one
            values = raw.view("<u2").reshape(-1, 2)[:, ::-1].copy().view("<f4").ravel() / 4.0
        else:
            values = raw.view("<f4").astype(np.float64)
        block = values.reshape(n_frames, words)[:, : 4 * n_points].reshape(n_frames, n_points, 4)
        xyz, residual = block[:, :, :3], block[:, :, 3]
    else:
        block = raw.view("<i2").reshape(n_frames, words)[:, : 4 * n_points].reshape(n_frames, n_points, 4)
        xyz, residual = block[:, :, :3] * abs(scale), block[:, :, 3].astype(np.float64)
    return xyz.transpose(2, 1, 0).astype(np.float64), residual.T[None].astype(np.float64)


def _ezc3d_read(path: Path, section: tuple[int, bytes] | None, intel: bytes | None = None) -> ezc3d.c3d:
    """ezc3d's reading of `path`, or of `intel` (the file's bytes as an Intel C3D) where given; with `section`
    (offset, bytes), of a temporary copy with that parameter section in place of the file's (_section_for_ezc3d),
    removed once read."""
    if section is None and intel is None:
        return ezc3d.c3d(str(path))
    with tempfile.TemporaryDirectory(prefix="calibrate-c3d-") as tmp:
        copy = Path(tmp) / path.name
        with (open(path, "rb") if intel is None else io.BytesIO(intel)) as src, open(copy, "wb") as dst:
            if section is None:
                shutil.copyfileobj(src, dst)
            else:
                offset, data = section
                dst.write(src.read(offset))
                dst.write(data)
                src.seek(offset + len(data))
                shutil.copyfileobj(src, dst)
        return ezc3d.c3d(str(copy))


def _c3d_param(params: object, group: str, name: str) -> list | np.ndarray | None:
    """Value of parameter GROUP:NAME, or None when it is absent."""
    try:
        return params[group][name]["value"]  # type: ignore[index]
    except (KeyError, TypeError):
        return None


def _first_number(value: list | np.ndarray | None) -> float | None:
    """First element of a numeric parameter value, or None."""
    if value is None:
        return None
    flat = np.asarray(value).ravel()
    if flat.size == 0:
        return None
    try:
        return float(flat[0])
    except (TypeError, ValueError):
        return None


def _c3d_strings(value: list | np.ndarray | None) -> list[str]:
    """A character parameter's entries as stripped strings (NUL padding removed)."""
    if value is None:
        return []
    return [str(v).replace("\x00", " ").strip() for v in np.asarray(value, dtype=object).ravel()]


def read_c3d(path: str | os.PathLike[str], *, strip_prefix: bool = True) -> Trial:
    """Read the marker trajectories of a C3D file (via ezc3d) into a trial in metres.

    Labels come from POINT:LABELS, LABELS2, ... for the first POINT:USED points;
    an empty label becomes ``unlabelled_<n>`` (n the 1-based point number) and a
    repeated label gets a suffix (``RASI_2``).  A subject prefix shared by the labels
    is removed unless ``strip_prefix`` is False (:func:`strip_subject_prefix`).  Points
    Vicon lists as angles, forces, moments, powers, scalars or reactions are left out.
    POINT:UNITS may be mm, cm or m (mm when absent).  Points with a negative residual,
    all three coordinates exactly zero, or a non-finite coordinate are gaps (NaN).
    The module docstring lists the vendor conventions this covers.
    """
    path = Path(path)
    size = check_input_file(path)
    layout = _check_c3d_layout(path, size)
    redo = "export it again from your capture software"
    try:
        c3d = _ezc3d_read(path, layout.section, layout.intel)
        params = c3d["parameters"]
        points = np.asarray(c3d["data"]["points"], dtype=np.float64)
        residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)
        header_first = int(c3d["header"]["points"]["first_frame"])
        header_rate = float(c3d["header"]["points"]["frame_rate"])
    except Exception as exc:  # noqa: BLE001 - ezc3d raises OSError, RuntimeError, ValueError, ... on bad files
        raise fail(path, f"not a readable C3D file (ezc3d: {one_line(exc) or type(exc).__name__})", redo) from None
    if layout.own_points is not None:
        points, residuals = _read_points(path if layout.intel is None else layout.intel, layout.own_points)

    if "POINT" not in params:
        raise fail(path, "C3D file has no POINT group, so no marker trajectories", redo)
    used = _first_number(_c3d_param(params, "POINT", "USED"))
    n_points = points.shape[1] if points.ndim == 3 else 0
    if used is not None:
        n_points = min(n_points, max(int(used), 0))
    n_frames = points.shape[2] if points.ndim == 3 else 0
    if layout.frames is not None and n_frames != layout.frames:
        if n_frames < layout.frames:
            raise fail(
                path,
                f"C3D file holds {layout.frames} frames but ezc3d reads only {n_frames} of them",
                "export the trial in parts of at most 65535 frames, or as a TRC file",
            )
        n_frames = layout.frames  # ezc3d read the zero padding after the last frame as frames
    if n_points == 0:
        raise fail(
            path, "C3D file contains no marker trajectories (POINT:USED is 0)", "export the trial with its markers"
        )
    if n_frames == 0:
        raise fail(path, "C3D file contains no frames", "export the trial again with its frames")

    raw_labels: list[str] = []
    k = 1
    while True:
        name = "LABELS" if k == 1 else f"LABELS{k}"
        value = _c3d_param(params, "POINT", name)
        if value is None:
            break
        raw_labels.extend(_c3d_strings(value))
        k += 1
    raw_labels = (raw_labels + [""] * n_points)[:n_points]

    raw_descriptions: list[str] = []
    k = 1
    while (value := _c3d_param(params, "POINT", "DESCRIPTIONS" if k == 1 else f"DESCRIPTIONS{k}")) is not None:
        raw_descriptions.extend(_c3d_strings(value))
        k += 1
    raw_descriptions = (raw_descriptions + [""] * n_points)[:n_points]

    kinds = _c3d_output_kinds(params, raw_labels)
    keep = [i for i, label in enumerate(raw_labels) if i not in kinds]
    if not keep:
        raise fail(
            path,
            "C3D file contains no marker trajectories, only model outputs (POINT:ANGLES, FORCES, PELO, ...)",
            "export the trial with its markers",
        )
    kept_labels = [raw_labels[i] for i in keep]
    outputs = sorted(kinds)
    output_labels = [raw_labels[i] for i in outputs]
    labels, output_labels = file_labels([kept_labels, output_labels], [[i + 1 for i in keep], [i + 1 for i in outputs]],
                                        strip_prefix)
    output_labels = list(output_labels)

    units_value = _c3d_strings(_c3d_param(params, "POINT", "UNITS"))
    units = units_value[0] if units_value else ""
    scale = (
        parse_units(units, path, "set POINT:UNITS to mm, cm or m", reading=True) if units else UNITS_TO_METRES["mm"]
    )

    rate = _first_number(_c3d_param(params, "POINT", "RATE"))
    if rate is None or not np.isfinite(rate) or rate <= 0:
        rate = header_rate
    if not np.isfinite(rate) or rate <= 0:
        raise fail(path, "C3D file gives no valid frame rate (POINT:RATE)", redo)

    # (frames, markers, 3) in metres: the one copy of the marker array besides ezc3d's, which the trial
    # takes over (read-only) rather than copies.
    xyz = np.empty((n_frames, len(keep), 3))
    np.multiply(points[:3, keep, :n_frames].transpose(2, 1, 0), scale, out=xyz)
    gap = ~np.isfinite(xyz).all(axis=2) | (xyz == 0.0).all(axis=2)
    if residuals.ndim == 3 and residuals.shape[1] >= n_points and residuals.shape[2] >= n_frames:
        gap |= (residuals[0, keep, :n_frames] < 0).T
    xyz[gap] = np.nan
    xyz.flags.writeable = False
    model_outputs: dict[str, np.ndarray] = {}
    output_kinds: dict[str, str] = {}
    output_units: dict[str, str] = {}
    for i, label in zip(outputs, output_labels, strict=True):
        kind, unit = kinds[i]
        factor, si = (scale, "m") if kind == "point" and not unit else output_factor(kind, unit)
        values = points[:3, i, :n_frames].T * factor
        bad = ~np.isfinite(values).all(axis=1)
        if kind == "point":
            bad |= (values == 0.0).all(axis=1)
        if residuals.ndim == 3 and residuals.shape[1] > i and residuals.shape[2] >= n_frames:
            bad |= residuals[0, i, :n_frames] < 0
        values[bad] = np.nan
        model_outputs[label], output_kinds[label], output_units[label] = values, kind, si
    first_frame = layout.first_frame if layout.first_frame is not None else max(header_first, 0)
    measurements = measurements_from_c3d(params, f"{path.name} PROCESSING")
    descriptions = {label: raw_descriptions[i] for i, label in zip(keep, labels, strict=True)
                    if raw_descriptions[i] and raw_descriptions[i].replace(" ", "").lower()
                    not in (label.replace(" ", "").lower(), raw_labels[i].replace(" ", "").lower())}
    del c3d, points, residuals  # ezc3d's copies, before the trial is made
    return Trial(labels=labels, markers=xyz, rate=rate, first_frame=first_frame, source=str(path),
                 model_outputs=model_outputs, output_kinds=output_kinds, output_units=output_units,
                 measurements=measurements, descriptions=descriptions)


def _c3d_output_kinds(params: dict, raw_labels: list[str]) -> dict[int, tuple[str, str]]:
    """Point index -> (kind, file unit) for every point that is a model output, not a marker.

    By the file's parameters: the labels listed in POINT:ANGLES, FORCES, ... (unit from
    ANGLE_UNITS, FORCE_UNITS, ...) and in every group POINT:TYPE_GROUPS names (pairs of group
    and singular name: ``ANGLES, ANGLE, MODELED_MARKERS, MODELED_MARKER``); then by name
    (:func:`is_model_output`), the units of the group of that kind.
    """
    groups = dict(_C3D_OUTPUT_GROUPS)
    singular = {"ANGLES": "ANGLE", "FORCES": "FORCE", "MOMENTS": "MOMENT", "POWERS": "POWER",
                "SCALARS": "SCALAR", "REACTIONS": "REACTION", "MODELED_MARKERS": "MODELED_MARKER"}
    pairs = [str(v).strip().upper() for v in _c3d_strings(_c3d_param(params, "POINT", "TYPE_GROUPS"))]
    for group, single in zip(pairs[0::2], pairs[1::2], strict=False):
        if group and group not in groups:
            groups[group] = single.lower() or group.lower()
            singular[group] = single
    unit_of: dict[str, str] = {}
    listed: dict[str, tuple[str, str]] = {}
    for group, kind in groups.items():
        units = _c3d_strings(_c3d_param(params, "POINT", f"{singular.get(group, group)}_UNITS"))
        unit = str(units[0]).strip() if units else ""
        unit_of.setdefault(kind, unit)
        for label in _c3d_strings(_c3d_param(params, "POINT", group)):
            if str(label).strip():
                listed.setdefault(str(label).strip(), (kind, unit))
    out: dict[int, tuple[str, str]] = {}
    for i, label in enumerate(raw_labels):
        label = str(label).strip()
        if not label:
            continue
        if label in listed:
            out[i] = listed[label]
        elif (kind := is_model_output(label)) is not None:
            out[i] = (kind, "" if kind == "point" else unit_of.get(kind, ""))
    return out




def write_c3d(path: str | os.PathLike[str], trial: Trial, units: str = "mm") -> None:
    """Write a trial's marker trajectories to a C3D file (float data, POINT:UNITS ``units``), and its model
    outputs after them.

    Gaps are written as coordinates 0 with residual -1 (the C3D "invalid point").  Each model output
    (:attr:`Trial.model_outputs`) is a point listed in the POINT parameter of its kind, as Vicon Nexus lists
    Plug-in Gait's (``MODELED_MARKERS`` for points, in ``units``; ``ANGLES`` in degrees, ``FORCES`` in N,
    ``MOMENTS`` in N mm, ``POWERS`` in W, with their ``*_UNITS``; the rest as they are), so that
    :func:`read_c3d` reads them back as model outputs, never as markers.  The markers' descriptions
    (:attr:`Trial.descriptions`) go in POINT:DESCRIPTIONS.  At most 65535 frames: ezc3d does not read longer
    files back whole.  The file is written next to its target and then moved into place.
    """
    path, key, scale = output_target(path, trial, units)
    if trial.n_frames > C3D_MAX_FRAMES:
        raise fail(
            path,
            f"{trial.n_frames} frames are more than a C3D file written here can hold ({C3D_MAX_FRAMES}; "
            "ezc3d reads back only that many)",
            "write a TRC file instead or split the trial with Trial.frames",
        )
    if trial.first_frame + 1 > C3D_MAX_FRAMES:
        raise fail(
            path,
            f"first frame {trial.first_frame} is past the last frame number a C3D header can hold "
            f"({C3D_MAX_FRAMES})",
            "write a TRC file instead or start the trial at an earlier frame",
        )
    outputs = list(trial.model_outputs)
    taken = set(trial.labels)
    clash = [label for label in outputs if label in taken]
    if clash:
        raise fail(path, f"model output {clash[0]!r} has a marker's label", "rename one of them")
    groups: dict[str, list[str]] = {}
    columns = [trial.markers / scale]  # (frames, markers, 3) in file units, then each output in its group's unit
    for label in outputs:
        kind = trial.output_kinds.get(label, "point")
        group, _, unit = _C3D_KIND_GROUPS.get(kind, ("MODELED_MARKERS", "", ""))
        factor = scale if kind == "point" else output_factor(kind, unit)[0] if unit else 1.0
        groups.setdefault(group, []).append(label)
        columns.append(np.asarray(trial.model_outputs[label], dtype=float)[:, None, :] / factor)
    xyz = np.concatenate(columns, axis=1)
    n_points = xyz.shape[1]
    gap = np.isnan(xyz).any(axis=2)  # (frames, points)
    points = np.zeros((4, n_points, trial.n_frames))
    points[:3] = np.where(gap[:, :, None], 0.0, xyz).transpose(2, 1, 0)
    points[3] = 1.0
    residuals = np.where(gap.T, -1.0, 0.0)[None, :, :]
    descriptions = [trial.descriptions.get(label, "") for label in trial.labels] + [""] * len(outputs)

    def write(staged: Path) -> None:  # the staged name ends in .c3d (ezc3d appends it to names without)
        c3d = ezc3d.c3d()
        c3d["parameters"]["POINT"]["RATE"]["value"] = [trial.rate]
        c3d["parameters"]["POINT"]["LABELS"]["value"] = list(trial.labels) + outputs
        c3d["parameters"]["POINT"]["UNITS"]["value"] = [key]
        if any(descriptions):
            c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = descriptions
        c3d["header"]["points"]["first_frame"] = trial.first_frame  # 0-based; stored 1-based in the file
        c3d["data"]["points"] = points
        c3d["data"]["meta_points"] = {"residuals": residuals}
        for group, unit_name, unit in _C3D_KIND_GROUPS.values():
            if group in groups:
                c3d.add_parameter("POINT", group, groups[group])
                if unit_name:
                    c3d.add_parameter("POINT", unit_name, [unit])
        if trial.measurements is not None:  # the session's subject measurements, where Nexus writes them
            for name, value in c3d_processing(trial.measurements).items():
                c3d.add_parameter("PROCESSING", name, [float(value)])
        c3d.write(str(staged))

    write_staged(path, "C3D", write, (Exception,))  # any ezc3d or OS failure: one line
