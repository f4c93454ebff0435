"""Reading files zcomp finds in an output folder or its cache (a job's ``report.json``,
``summary*.json``, ``eval.json``/``eval.csv``, a preview's JSON, a bundle's
``meta.json``): what lies there may be anything, so a file is read only when it is a
regular file under a size cap, and a damaged one -- not JSON, not UTF-8, nested past
the parser's depth, a FIFO that would block the reader, ``/dev/zero`` that would be
read until memory runs out -- raises ``JsonFileError`` (a ``ValueError``) with the
reason, which callers turn into "missing, with a note"."""

from __future__ import annotations

import json
import os
import stat

# The largest JSON file read from an output folder: a summary of 100 000 jobs is about
# 20 MB, a job's report under 100 kB; 256 MiB is far above both and keeps a hostile
# file's parse within a few GB of memory.
MAX_JSON_BYTES = 256 << 20


class JsonFileError(ValueError):
    """A JSON file that cannot be read; the message says why (without the path)."""


def read_json_file(path, max_bytes: int = MAX_JSON_BYTES):
    """The JSON document of the regular file ``path``. Raises ``FileNotFoundError``
    when there is none, ``JsonFileError`` when it is not a regular file, is over
    ``max_bytes``, or is not UTF-8 JSON (depth included), and ``OSError`` when it cannot
    be read."""
    return _decode(read_regular_bytes(path, max_bytes, "JSON file"))


def _decode(raw: bytes):
    try:
        return json.loads(raw.decode("utf-8"))
    except RecursionError:
        raise JsonFileError("JSON nested deeper than the parser allows") from None
    except UnicodeDecodeError as exc:
        raise JsonFileError(f"not UTF-8 ({exc.reason} at byte {exc.start})") from None
    except ValueError as exc:
        raise JsonFileError(f"not JSON ({str(exc)[:120]})") from None


def read_regular_bytes(path, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of ``path`` when it is a regular file of at most ``max_bytes``; opened
    without blocking (a FIFO would wait for a writer forever) and checked on the open
    file (no race with a swap between a check and the read)."""
    fd = os.open(os.fspath(path), os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise JsonFileError(f"{file_kind(st.st_mode)}, not a regular file: not read")
        if st.st_size > max_bytes:
            raise JsonFileError(f"{st.st_size:,} bytes, over the {max_bytes:,} a {what} may have; not read")
        chunks, n = [], 0
        while chunk := os.read(fd, 1 << 20):
            n += len(chunk)
            if n > max_bytes:  # grown since the check
                raise JsonFileError(f"over the {max_bytes:,} bytes a {what} may have; not read")
            chunks.append(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def file_kind(mode: int) -> str:
    """What a file of ``mode`` (``st_mode``) is, in words ("a FIFO (named pipe)")."""
    return ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a character device" if stat.S_ISCHR(mode)
            else "a block device" if stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a folder" if stat.S_ISDIR(mode) else "not a file")


__all__ = ["JsonFileError", "MAX_JSON_BYTES", "file_kind", "read_json_file", "read_regular_bytes"]
