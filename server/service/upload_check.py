"""The check of an uploaded file, run in a child process with a memory limit.

An upload lands in a quarantine directory (``POST /api/uploads``); :func:`run_check`
checks it in a new process (forked from a server process that has the readers imported
already: ``multiprocessing``'s forkserver), niced, with ``RLIMIT_AS`` set before
anything is read, and gets one answer back: what the file holds, or why it is refused.
Whatever the file does to its reader (a decompression bomb, a
parser's recursion, a crash) happens in that process, not in the service.

The child bounds the work before parsing: a CSV's rows and columns are counted on the
raw bytes, a ``.mat``'s decompressed size is read from its element headers
(:func:`mat_expanded_size`: each compressed element's first bytes only) and refused
above the limit before anything is expanded; a sidecar must be a small JSON object with
keys of the right types. Then the log loader's own checks run
(:func:`server.records.measured_log.load_log`).
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Required, TypedDict

#: MAT v5 data types (MATLAB's "MAT-File Format", table 1-1)
MI_MATRIX, MI_COMPRESSED = 14, 15
#: bytes per element of each MATLAB array class (mxDOUBLE_CLASS = 6, ...)
CLASS_BYTES = {4: 2, 5: 1, 6: 8, 7: 4, 8: 1, 9: 1, 10: 2, 11: 2, 12: 4, 13: 4, 14: 8, 15: 8}
#: largest sidecar [bytes]
SIDECAR_MAX = 1 << 20


@dataclass(frozen=True)
class Limits:
    """Bounds of one check: a ``.mat``'s expanded size, a CSV's rows and columns, the
    child's address space and its time."""

    expanded_bytes: int
    rows: int
    columns: int
    memory_mb: int
    timeout_s: float


class Refused(Exception):
    """The file is refused before the loader runs (a bound, a malformed header)."""


# ------------------------------------------------------------------ the child's side
def mat_expanded_size(path: Path, limit: int) -> int:
    """The bytes a MAT file's variables take once expanded, from their headers.

    For a compressed element only the first bytes of its zlib stream are inflated (the
    inner matrix tag, array flags and dimensions); the size counted is the larger of the
    declared element size and dimensions x class bytes.

    Raises
    ------
    Refused
        Not a MAT v5/v7 file (v7.3 is HDF5, not supported), a truncated element, or more
        than ``limit`` bytes once expanded (refused as soon as the sum passes it).
    """
    with path.open("rb") as fh:
        head = fh.read(128)
        if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
            if _is_v4(head):  # a v4 file has no compression: it expands to its own size
                return path.stat().st_size
            raise Refused(f"{path.name}: not a MATLAB .mat file (no v4 or v5 MAT-file header)")
        if head[124:126] in (b"\x02\x00", b"\x00\x02"):
            raise Refused(
                f"{path.name}: MATLAB v7.3 (HDF5) files are not supported; save with -v7 "
                "or export a CSV"
            )
        end = "<" if head[126:128] == b"IM" else ">"
        total = 0
        while True:
            tag = fh.read(8)
            if not tag:
                return total
            if len(tag) < 8:
                raise Refused(f"{path.name}: truncated element header at byte {fh.tell()}")
            mtype, nbytes = struct.unpack(end + "II", tag)
            if mtype >> 16:  # small data element: 4 bytes of data in the tag
                continue
            if mtype == MI_COMPRESSED:
                data = fh.read(min(nbytes, 4096))
                size = _compressed_size(path, data, end)
                fh.seek(nbytes - len(data), os.SEEK_CUR)
            else:
                size = _matrix_size(head=tag + fh.read(min(nbytes, 64)), end=end)
                fh.seek(nbytes + (-nbytes % 8) - min(nbytes, 64), os.SEEK_CUR)
            total += size
            if total > limit:
                raise Refused(
                    f"{path.name}: its variables expand to more than {limit} bytes "
                    f"(at least {total} declared in the file's headers); the limit is "
                    "CUTWATCH_UPLOAD_MAX_MB"
                )


def _is_v4(head: bytes) -> bool:
    """True when ``head`` starts like a MAT v4 variable (type MOPT, rows, columns,
    imaginary flag, name length; little- or big-endian)."""
    if len(head) < 20:
        return False
    for end in "<>":
        mopt, rows, cols, imag, namlen = struct.unpack(end + "5i", head[:20])
        m, o, p, t = mopt // 1000, mopt // 100 % 10, mopt // 10 % 10, mopt % 10
        if 0 <= mopt < 5000 and m <= 4 and o == 0 and p <= 5 and t <= 2 and rows >= 0 \
                and cols >= 0 and imag in (0, 1) and 1 <= namlen <= 64:  # fmt: skip
            return True
    return False


def _compressed_size(path: Path, data: bytes, end: str) -> int:
    try:
        inner = zlib.decompressobj().decompress(data, 128)  # at most 128 bytes inflated
    except zlib.error as exc:
        raise Refused(f"{path.name}: a compressed element is not valid zlib ({exc})") from None
    if len(inner) < 8:
        raise Refused(f"{path.name}: a compressed element too short to hold a header")
    return _matrix_size(inner, end)


def _matrix_size(head: bytes, end: str) -> int:
    """8 + the declared size of a matrix element, or its dimensions x class bytes when
    larger (``head``: the element's tag and first bytes)."""
    mtype, nbytes = struct.unpack(end + "II", head[:8])
    size = 8 + nbytes
    if mtype != MI_MATRIX or len(head) < 32:
        return size
    # array flags: a tag (8) and 8 bytes (class in the low byte, complex flag 0x0800)
    flags = struct.unpack(end + "I", head[16:20])[0]
    cls, cplx = flags & 0xFF, bool(flags & 0x0800)
    dtag, dbytes = struct.unpack(end + "II", head[24:32])
    if dtag >> 16:  # dimensions as a small element: two int32 in the tag's data
        dims = struct.unpack(end + "ii", head[28:36]) if len(head) >= 36 else ()
    else:
        n = min(dbytes // 4, (len(head) - 32) // 4)
        dims = struct.unpack(end + f"{n}i", head[32 : 32 + 4 * n])
    count = 1
    for d in dims:
        count *= max(int(d), 0)
    return max(size, count * CLASS_BYTES.get(cls, 8) * (2 if cplx else 1))


def scan_csv(path: Path, limits: Limits) -> None:
    """Count a CSV's rows and its header's columns on the raw bytes, before parsing.

    Raises
    ------
    Refused
        More columns or rows than the limits allow, or a header line over 64 KiB.
    """
    with path.open("rb") as fh:
        header = fh.readline(65536)
        if len(header) >= 65536 and not header.endswith(b"\n"):
            raise Refused(f"{path.name}: header line longer than 65536 bytes")
        cols = header.count(b",") + 1
        if cols > limits.columns:
            raise Refused(
                f"{path.name}: {cols} columns in the header; at most {limits.columns} "
                "(CUTWATCH_UPLOAD_MAX_COLUMNS)"
            )
        rows = 0
        while chunk := fh.read(1 << 20):
            rows += chunk.count(b"\n")
            if rows > limits.rows:
                raise Refused(
                    f"{path.name}: more than {limits.rows} rows (CUTWATCH_UPLOAD_MAX_ROWS)"
                )


class LogFacts(TypedDict, total=False):
    """What a check found in a measured log (nothing for a sidecar)."""

    samples: int  # rows
    sample_time: float  # [s]
    log_kind: str | None  # the log's model kind (None: not said)


class CheckAnswer(LogFacts, total=False):
    """A check's answer: ``ok`` and the log's facts, or the refusal's ``error``."""

    ok: Required[bool]
    error: str  # why not (``ok`` False)


def check_file(path: Path, what: str, limits: Limits) -> LogFacts:
    """The check itself (in the child): ``what`` is ``sidecar`` or ``log``."""
    from server.records.measured_log import check_sidecar, load_log

    if what == "sidecar":
        raw = path.read_bytes()
        if len(raw) > SIDECAR_MAX:
            raise Refused(f"{path.name}: a sidecar of {len(raw)} bytes; at most {SIDECAR_MAX}")
        try:
            data = json.loads(raw.decode("utf-8"))
        except UnicodeDecodeError as exc:
            raise Refused(f"{path.name}: not UTF-8 text ({exc.reason})") from None
        except ValueError as exc:
            raise Refused(f"{path.name}: not valid JSON ({exc})") from None
        except RecursionError:
            raise Refused(f"{path.name}: JSON nested too deeply") from None
        check_sidecar(Path(path.name), data)
        return {}
    if path.suffix.lower() == ".mat":
        mat_expanded_size(path, limits.expanded_bytes)
    else:
        scan_csv(path, limits)
    log = load_log(path)
    return {"samples": len(log["t"]), "sample_time": log.sample_time, "log_kind": log.kind}


def _child(name: str, where: str, what: str, limits: Limits, conn: Any) -> None:
    """The checking process: beside the file, under its memory limit, niced; sends one
    answer (``{"ok": True, ...}`` or ``{"ok": False, "error": msg}``) down ``conn``."""
    import resource

    lim = limits
    os.chdir(where)  # messages name the file, never its directory
    cap = lim.memory_mb * 1024 * 1024
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    os.nice(10)  # the service's loop comes first
    try:
        out: CheckAnswer = {"ok": True, **check_file(Path(name), what, lim)}
    except MemoryError:
        out = {"ok": False, "error": f"{name}: checking it needed more than "
               f"{lim.memory_mb} MB (CUTWATCH_UPLOAD_CHECK_MB)"}  # fmt: skip
    except RecursionError:
        out = {"ok": False, "error": f"{name}: nested too deeply to read"}
    except Exception as exc:  # a named error, or what the reader tripped on, named
        from server.errors import CutwatchError

        named = isinstance(exc, Refused | CutwatchError)
        msg = str(exc) if named else f"{name}: not readable ({type(exc).__name__}: {exc})"
        out = {"ok": False, "error": msg[:2000]}
    conn.send(out)
    conn.close()


# ------------------------------------------------------------------ the service's side
#: checks are forked from a server process that has the readers imported already (a
#: fresh interpreter would spend seconds importing numpy and scipy for every upload);
#: each check is a new process, so nothing one file does outlives its check
_CTX = multiprocessing.get_context("forkserver")
_CTX.set_forkserver_preload(["server.service.upload_check", "server.records.measured_log",
                             "scipy.io"])  # fmt: skip


def _run(path: Path, what: str, limits: Limits) -> CheckAnswer:
    recv, send = _CTX.Pipe(duplex=False)
    p = _CTX.Process(
        target=_child,
        args=(path.name, str(path.parent), what, limits, send),
        name=f"upload-check-{path.name}",
        daemon=True,
    )
    p.start()
    send.close()
    try:
        if recv.poll(limits.timeout_s):
            out: CheckAnswer = recv.recv()
            return out
        p.kill()
        return {"ok": False, "error": f"{path.name}: its check took over {limits.timeout_s:g} s"}
    except EOFError:  # the process died without an answer
        p.join(5)
        code = p.exitcode
        how = f"signal {-code}" if code is not None and code < 0 else f"status {code}"
        return {
            "ok": False,
            "error": f"{path.name}: its check ended without an answer ({how}: over its "
            f"memory limit of {limits.memory_mb} MB, CUTWATCH_UPLOAD_CHECK_MB, or a crash)",
        }
    finally:
        recv.close()
        p.join(5)


def warm() -> None:
    """Start the server process that checks are forked from (the service's start-up
    calls this on a thread, so that the first upload does not wait for the imports)."""
    recv, send = _CTX.Pipe(duplex=False)
    p = _CTX.Process(target=_noop, args=(send,), daemon=True)
    p.start()
    send.close()
    recv.poll(120)
    recv.close()
    p.join(5)


def _noop(conn: Any) -> None:
    conn.send(None)
    conn.close()


async def run_check(path: Path, what: str, limits: Limits) -> CheckAnswer:
    """Check ``path`` (``sidecar`` or ``log``) in a child process; the answer of
    :func:`_child`. Messages name the file by its name only (the child runs beside it)."""
    return await asyncio.to_thread(_run, path, what, limits)
