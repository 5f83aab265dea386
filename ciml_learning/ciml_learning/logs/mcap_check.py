"""Checked bag files: MCAP CRCs written by our writer and verified before any read; db3 integrity.

MCAP (https://mcap.dev/spec) carries three CRC-32s, each optional (0 = not computed):
a chunk's `uncompressed_crc` (its records before compression), the DataEnd record's
`data_section_crc` (every byte from the magic to DataEnd) and the Footer's `summary_crc`
(the summary section and the footer's own first fields). rosbags' writer leaves all three
0, so a flipped byte inside a chunk was read as a valid message (torques of 1e278).

- seal_mcap(path): computes the three CRCs of a finished file and writes them in place
  (BagWriter does it before publishing the bag).
- verify_mcap(path): magic, record framing, footer and summary offsets, then the CRCs
  that are present; where the data CRC is absent (bags of other writers), each chunk's
  CRC or else that it decompresses to its declared size. A failure is a BagCorruptError
  naming the file and byte offset (and what `mcap recover` can still save).
- verify_db3(path): sqlite's quick_check, read-only.
- check_bag(path): every .mcap/.db3 file of a bag folder (bagio's reader calls it first).
"""
from __future__ import annotations

import mmap
import os
import sqlite3
import struct
from binascii import crc32
from dataclasses import dataclass
from pathlib import Path

from ciml_learning.core.errors import CimlError

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_CHUNK, OP_DATA_END = 0x01, 0x02, 0x06, 0x0F
FOOTER_SIZE = 1 + 8 + 20  # opcode, length, summary_start, summary_offset_start, summary_crc
_BLOCK = 1 << 24


class BagCorruptError(CimlError):
    """A bag file fails its integrity checks."""


@dataclass
class Chunk:
    offset: int            # of the record's opcode
    crc_at: int            # of uncompressed_crc
    uncompressed_size: int
    crc: int
    compression: str
    data_at: int
    data_size: int


@dataclass
class Layout:
    size: int
    chunks: list[Chunk]
    data_end: int          # offset of the DataEnd record (-1: none)
    data_crc: int
    footer: int            # offset of the footer record
    summary_start: int
    summary_crc: int


def _crc(buf, start: int, stop: int) -> int:
    c = 0
    for a in range(start, stop, _BLOCK):
        c = crc32(buf[a:min(stop, a + _BLOCK)], c)
    return c


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd  # type: ignore[import-not-found,no-redef]
        return zstd.decompress(data)
    if compression == "lz4":
        from lz4.frame import decompress  # type: ignore[import-untyped]

        return decompress(data)
    raise ValueError(f"unknown chunk compression {compression!r}")


def _layout(buf, name: str, file: str | None = None) -> Layout:
    """Frame every record of the data section and read the footer (BagCorruptError if broken)."""
    size = len(buf)
    recover = f"`mcap recover {file or name}` may save the complete chunks"
    if size < 2 * len(MAGIC) + FOOTER_SIZE or buf[:len(MAGIC)] != MAGIC:
        raise BagCorruptError(f"{name}: not an MCAP file (bad magic at byte 0)")
    if buf[size - len(MAGIC):] != MAGIC:
        raise BagCorruptError(f"{name}: no MCAP end magic at byte {size - len(MAGIC)} (truncated or overwritten); "
                              + recover)
    footer = size - len(MAGIC) - FOOTER_SIZE
    op, length = struct.unpack_from("<BQ", buf, footer)
    if op != OP_FOOTER or length != 20:
        raise BagCorruptError(f"{name}: bad MCAP footer at byte {footer}; " + recover)
    summary_start, summary_offset_start, summary_crc = struct.unpack_from("<QQI", buf, footer + 9)
    if summary_start and not (len(MAGIC) < summary_start <= footer) or \
            summary_offset_start and not (summary_start <= summary_offset_start <= footer):
        raise BagCorruptError(f"{name}: MCAP footer at byte {footer} points outside the file; " + recover)
    chunks: list[Chunk] = []
    pos, data_end, data_crc = len(MAGIC), -1, 0
    stop = summary_start or footer
    while pos < stop:
        if pos + 9 > stop:
            raise BagCorruptError(f"{name}: record framing broken at byte {pos}; " + recover)
        op, length = struct.unpack_from("<BQ", buf, pos)
        end = pos + 9 + length
        if end > stop or (pos == len(MAGIC) and op != OP_HEADER):
            raise BagCorruptError(f"{name}: record framing broken at byte {pos} (opcode {op:#x}, length {length}); "
                                  + recover)
        if op == OP_CHUNK:
            try:
                _, _, usize, crc, clen = struct.unpack_from("<QQQII", buf, pos + 9)
                comp = bytes(buf[pos + 9 + 32:pos + 9 + 32 + clen]).decode("ascii")
                (dsize,) = struct.unpack_from("<Q", buf, pos + 9 + 32 + clen)
            except (struct.error, UnicodeDecodeError):
                raise BagCorruptError(f"{name}: chunk at byte {pos} has a corrupt header; " + recover) from None
            data_at = pos + 9 + 32 + clen + 8
            if data_at + dsize != end:
                raise BagCorruptError(f"{name}: chunk at byte {pos} has inconsistent sizes; " + recover)
            chunks.append(Chunk(pos, pos + 9 + 24, usize, crc, comp, data_at, dsize))
        elif op == OP_DATA_END:
            data_end = pos
            (data_crc,) = struct.unpack_from("<I", buf, pos + 9) if length >= 4 else (0,)
        elif op == OP_FOOTER:
            raise BagCorruptError(f"{name}: a footer inside the data section at byte {pos}; " + recover)
        pos = end
        if data_end >= 0:
            break
    if summary_start and pos != summary_start and data_end < 0:
        raise BagCorruptError(f"{name}: data section ends at byte {pos}, the footer says {summary_start}; " + recover)
    return Layout(size, chunks, data_end, data_crc, footer, summary_start, summary_crc)


def _summary_crc_span(lay: Layout) -> tuple[int, int]:
    start = lay.summary_start or lay.footer
    return start, lay.footer + 1 + 8 + 16


def _chunk_ok(buf, c: Chunk) -> str | None:
    """None if the chunk decodes to its size and CRC, else why not."""
    try:
        raw = _decompress(c.compression, bytes(buf[c.data_at:c.data_at + c.data_size]), c.uncompressed_size)
    except Exception as err:  # noqa: BLE001 - any decoder failure means a corrupt chunk
        return f"does not decompress ({type(err).__name__})"
    if len(raw) != c.uncompressed_size:
        return f"decompresses to {len(raw)} bytes, not {c.uncompressed_size}"
    if c.crc and crc32(raw) != c.crc:
        return "fails its CRC"
    return None


def _bad_chunk(buf, lay: Layout, name: str, c: Chunk, why: str, file: str) -> BagCorruptError:
    others = len(lay.chunks) - 1
    return BagCorruptError(f"{name}: chunk at byte {c.offset} {why}; `mcap recover {file}` can save the messages "
                           f"of the other {others} chunk{'s' if others != 1 else ''}")


def _open_map(path: Path, write: bool = False) -> tuple:
    mode = "r+b" if write else "rb"
    f = open(path, mode)  # noqa: SIM115 - closed by the caller through the context manager below
    try:
        return f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_WRITE if write else mmap.ACCESS_READ)
    except (ValueError, OSError):
        f.close()
        raise


def verify_mcap(path: str | os.PathLike, bag: str | None = None) -> None:
    """Check an MCAP file's framing and CRCs (module docstring); BagCorruptError (one line)."""
    path = Path(path)
    name = f"bag {bag}: {path.name}" if bag else str(path)
    try:
        f, buf = _open_map(path)
    except ValueError:
        raise BagCorruptError(f"{name}: empty file") from None
    except OSError as err:
        raise BagCorruptError(f"{name}: cannot read ({err.strerror or err})") from None
    try:
        lay = _layout(buf, name, str(path))
        if lay.data_end >= 0 and lay.data_crc:
            if _crc(buf, 0, lay.data_end) != lay.data_crc:
                for c in lay.chunks:  # name the chunk if one is at fault
                    why = _chunk_ok(buf, c)
                    if why:
                        raise _bad_chunk(buf, lay, name, c, why, str(path))
                raise BagCorruptError(f"{name}: the data section (bytes 0–{lay.data_end}) fails its CRC outside the "
                                      f"chunks (schemas, channels or message indexes); `mcap recover {path}` can "
                                      "rebuild them from the chunks")
        else:
            for c in lay.chunks:
                why = _chunk_ok(buf, c)
                if why:
                    raise _bad_chunk(buf, lay, name, c, why, str(path))
        if lay.summary_crc:
            a, b = _summary_crc_span(lay)
            if _crc(buf, a, b) != lay.summary_crc:
                raise BagCorruptError(f"{name}: the summary section (bytes {a}–{b}) fails its CRC; `mcap recover "
                                      f"{path}` can rebuild it from the {len(lay.chunks)} chunks")
    finally:
        buf.close()
        f.close()


def seal_mcap(path: str | os.PathLike) -> int:
    """Write the chunk, data-section and summary CRCs of a complete MCAP file in place; the
    number of chunks sealed. Run before the file is published (BagWriter)."""
    path = Path(path)
    f, buf = _open_map(path, write=True)
    try:
        lay = _layout(buf, str(path))
        for c in lay.chunks:
            raw = _decompress(c.compression, bytes(buf[c.data_at:c.data_at + c.data_size]), c.uncompressed_size)
            struct.pack_into("<I", buf, c.crc_at, crc32(raw))
        if lay.data_end >= 0:
            struct.pack_into("<I", buf, lay.data_end + 9, _crc(buf, 0, lay.data_end))
        a, b = _summary_crc_span(lay)
        struct.pack_into("<I", buf, lay.footer + 9 + 16, _crc(buf, a, b))
        buf.flush()
        return len(lay.chunks)
    finally:
        buf.close()
        f.close()


def verify_db3(path: str | os.PathLike, bag: str | None = None) -> None:
    """sqlite's quick_check on a rosbag2 db3 file (read-only); BagCorruptError (one line)."""
    path = Path(path)
    name = f"bag {bag}: {path.name}" if bag else str(path)
    try:
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            rows = con.execute("PRAGMA quick_check").fetchall()
        finally:
            con.close()
    except sqlite3.Error as err:
        raise BagCorruptError(f"{name}: not a readable SQLite database ({err}); try 'ros2 bag reindex' or "
                              "sqlite3's .recover") from None
    problems = [r[0] for r in rows if r and r[0] != "ok"]
    if problems:
        raise BagCorruptError(f"{name}: SQLite integrity check failed ({len(problems)} problem"
                              f"{'s' if len(problems) != 1 else ''}, first: {' '.join(str(problems[0]).split())}); "
                              "sqlite3's .recover can save the intact rows")


def check_bag(path: str | os.PathLike) -> None:
    """Verify every MCAP and db3 file of a bag (a folder, or one file)."""
    p = Path(path)
    files = [p] if p.is_file() else sorted(x for x in p.iterdir() if x.suffix in (".mcap", ".db3") and x.is_file()) \
        if p.is_dir() else []
    for x in files:
        if x.suffix == ".mcap":
            verify_mcap(x, str(path))
        elif x.suffix == ".db3":
            verify_db3(x, str(path))
