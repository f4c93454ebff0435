"""Guarding an output folder shared by runs: locks, containment, hashes, litter.

* **Locks.** A run holds ``OUT/.zcomp-job-<name>.lock`` for every job it selected
  (``fcntl.flock``, released by the kernel when the process dies, even by ``kill -9``:
  a lock left by a dead process is simply taken over). Two runs (or two ``--shard``
  runs) never hold the same job, so shards of one manifest write side by side while a
  second run of the same jobs is refused, naming the first one's pid. Every run also
  registers ``.zcomp-run-<pid>.lock`` with its manifest: a run of *another* manifest
  into the same folder at the same time is refused (its outputs would be mixed in).
  ``.zcomp-summary.lock`` serialises the read-merge-write of ``summary.json``. Lock
  files are removed when released: a finished run leaves none.
* **Containment.** Every path zcomp writes must resolve inside its output root: a job
  folder that is a symbolic link (or leads out of the root) is refused.
* **Digests.** Files are fingerprinted by content (sha256), cached by path, size and
  mtime in ``<cache root>/file-hashes.json``, so ``touch`` or moving a project does not
  change a fingerprint and an unchanged file is read once.
* **Litter.** Temporary files of runs that were killed (``.*.tmp*`` in job folders,
  Blender's ``/tmp/zcomp-job-<pid>-*`` and ``<cache>/intrinsics/.work-<pid>-*``) are
  removed when their process is gone.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from zcomp_cli.errors import UsageError

LOCK_PREFIX = ".zcomp-"


# ----------------------------------------------------------------------------- pids
def pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# ----------------------------------------------------------------------------- locks
class _FileLock:
    """An exclusive ``flock`` on a file that names its holder (JSON: pid, what)."""

    def __init__(self, path: Path, info: dict):
        self.path = path
        self.info = info
        self.fd: int | None = None

    def try_acquire(self) -> dict | None:
        """Take the lock; None on success, else what the current holder wrote."""
        for _ in range(20):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_holder(fd)
                os.close(fd)
                return holder or {"pid": None}
            # The previous holder may have unlinked the file between our open and flock:
            # then we hold a lock on a dead inode; try again on the current file.
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            os.ftruncate(fd, 0)
            os.write(fd, json.dumps(self.info).encode())
            self.fd = fd
            return None
        raise UsageError(f"cannot take the lock {self.path} (it keeps changing)")

    def release(self) -> None:
        if self.fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        with contextlib.suppress(OSError):
            os.close(self.fd)
        self.fd = None


def _read_holder(fd: int) -> dict | None:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        data = os.read(fd, 4096)
        return json.loads(data.decode() or "null")
    except (OSError, ValueError):
        return None


class OutputLock:
    """Locks of one run on ``out_root`` (see the module docstring). Use as a context
    manager, or ``acquire()`` / ``release()``."""

    def __init__(self, out_root: Path, manifest_path: Path, manifest_id: str, job_names: list[str],
                 what: str = "zcomp composite"):
        self.out_root = Path(out_root)
        self.dir = self.out_root
        self.manifest_path = str(manifest_path)
        self.manifest_id = manifest_id
        self.job_names = list(job_names)
        self.what = what
        self._locks: list[_FileLock] = []

    def _info(self, **extra) -> dict:
        return {"pid": os.getpid(), "command": self.what, "manifest": self.manifest_path,
                "manifest_id": self.manifest_id, "started": time.time(), **extra}

    def acquire(self) -> "OutputLock":
        self.dir.mkdir(parents=True, exist_ok=True)
        try:
            run = _FileLock(self.dir / f"{LOCK_PREFIX}run-{os.getpid()}.lock", self._info())
            if run.try_acquire() is not None:  # our own pid: only a forked copy of us
                raise UsageError(f"{self.out_root} is already locked by this process")
            self._locks.append(run)
            self._check_other_runs()
            for name in self.job_names:
                lk = _FileLock(self.dir / f"{LOCK_PREFIX}job-{name}.lock", self._info(job=name))
                holder = lk.try_acquire()
                if holder is not None:
                    pid = holder.get("pid")
                    raise UsageError(
                        f"job {name!r} in {self.out_root} is being made by another zcomp run "
                        f"(pid {pid}{', ' + str(holder.get('command')) if holder.get('command') else ''}); "
                        "wait for it to finish, or use another --out")
                self._locks.append(lk)
            self._sweep_stale_job_locks()
        except BaseException:
            self.release()
            raise
        return self

    def _check_other_runs(self) -> None:
        for p in sorted(self.dir.glob(f"{LOCK_PREFIX}run-*.lock")):
            if p.name == f"{LOCK_PREFIX}run-{os.getpid()}.lock":
                continue
            probe = _FileLock(p, {})
            holder = probe.try_acquire()
            if holder is None:  # nobody holds it: a dead run's file
                probe.release()
                continue
            if holder.get("manifest_id") not in (None, self.manifest_id):
                raise UsageError(
                    f"{self.out_root} is being written by another zcomp run (pid {holder.get('pid')}) "
                    f"from another manifest ({holder.get('manifest')}); outputs of two manifests would "
                    "be mixed: wait for it, or use another --out")

    def _sweep_stale_job_locks(self) -> None:
        """Lock files of jobs this run does not take, left by killed runs: removed when
        nobody holds them (a live run's locks cannot be taken, so they stay)."""
        mine = {lk.path.name for lk in self._locks}
        for p in self.dir.glob(f"{LOCK_PREFIX}job-*.lock"):
            if p.name in mine:
                continue
            probe = _FileLock(p, {})
            with contextlib.suppress(OSError):
                if probe.try_acquire() is None:
                    probe.release()

    def release(self) -> None:
        for lk in reversed(self._locks):
            lk.release()
        self._locks.clear()

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False


@contextlib.contextmanager
def summary_lock(out_root: Path, timeout_s: float = 60.0):
    """Serialise read-merge-write of ``summary.json`` between concurrent runs (shards)."""
    lock = _FileLock(Path(out_root) / f"{LOCK_PREFIX}summary.lock", {"pid": os.getpid()})
    deadline = time.monotonic() + timeout_s
    while lock.try_acquire() is not None:
        if time.monotonic() > deadline:
            raise UsageError(f"{out_root}: another run holds the summary lock for over {timeout_s:.0f} s")
        time.sleep(0.02)
    try:
        yield
    finally:
        lock.release()


# ----------------------------------------------------------------------------- containment
def check_inside(root: Path, path: Path, field: str) -> None:
    """Refuse ``path`` unless it (and every folder on the way) resolves inside ``root``
    without following a symbolic link out of it. ``field`` names what set the path."""
    root_r = Path(root).resolve()
    p = Path(root)
    for part in Path(path).relative_to(root).parts:
        p = p / part
        if p.is_symlink():
            raise UsageError(f"{field}: {p} is a symbolic link; zcomp writes only inside {root}")
    r = Path(path).resolve()
    if r != root_r and root_r not in r.parents:
        raise UsageError(f"{field}: {path} resolves to {r}, outside {root}")


# ----------------------------------------------------------------------------- digests
def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


class DigestCache:
    """sha256 of files, remembered by (absolute path, size, mtime_ns)."""

    def __init__(self, store: Path | None):
        self.store = store
        self._data: dict[str, list] = {}
        self._dirty = False
        if store is not None and store.is_file():
            try:
                data = json.loads(store.read_text())
                if isinstance(data, dict):
                    self._data = data
            except (OSError, ValueError):
                pass

    def digest(self, path: Path) -> str:
        """Content hash of a file, or of a folder's files (names and contents)."""
        path = Path(path)
        if path.is_dir():
            h = hashlib.sha256()
            for f in sorted(p for p in path.rglob("*") if p.is_file()):
                h.update(str(f.relative_to(path)).encode() + b"\0" + self.digest(f).encode())
            return h.hexdigest()
        st = path.stat()
        key = str(path.resolve())
        hit = self._data.get(key)
        if isinstance(hit, list) and len(hit) == 3 and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            return hit[2]
        d = sha256_file(path)
        self._data[key] = [st.st_size, st.st_mtime_ns, d]
        self._dirty = True
        return d

    def save(self) -> None:
        """Best effort: an unwritable cache only costs re-hashing next time."""
        if not self._dirty or self.store is None:
            return
        from zcomp_cli.imageio import write_json_atomic

        if len(self._data) > 20000:  # keep the file small: drop the oldest half
            self._data = dict(list(self._data.items())[-10000:])
        with contextlib.suppress(Exception):
            write_json_atomic(self.store, self._data)
        self._dirty = False


def output_record(path: Path) -> dict:
    return {"bytes": path.stat().st_size, "sha256": sha256_file(path)}


def verify_outputs(job_dir: Path, outputs) -> str | None:
    """None when every recorded output is present with its size and hash, else why not."""
    if not isinstance(outputs, dict) or not outputs:
        return "its report records no output hashes"
    for name, rec in outputs.items():
        p = job_dir / name
        if not isinstance(rec, dict) or not p.is_file():
            return f"{name} is missing"
        size = p.stat().st_size
        if size == 0 or size != rec.get("bytes"):
            return f"{name} has {size} bytes, {rec.get('bytes')} were written"
        if sha256_file(p) != rec.get("sha256"):
            return f"{name} changed since it was written"
    return None


# ----------------------------------------------------------------------------- litter
def clean_job_folder(job_dir: Path) -> int:
    """Remove temporary files (``.<name>.*.tmp*``) a killed write left in a job folder."""
    n = 0
    for d in (job_dir, job_dir / "debug"):
        if not d.is_dir() or d.is_symlink():
            continue
        for p in d.iterdir():
            if p.name.startswith(".") and ".tmp" in p.name and p.is_file() and not p.is_symlink():
                with contextlib.suppress(OSError):
                    p.unlink()
                    n += 1
    return n


def clean_root_temporaries(out_root: Path) -> int:
    """Temporary summary files at the top of OUT (call under ``summary_lock``)."""
    n = 0
    for p in Path(out_root).glob(".summary.*.tmp*"):
        with contextlib.suppress(OSError):
            p.unlink()
            n += 1
    return n


def _pid_of(name: str, prefix: str) -> int | None:
    rest = name[len(prefix):]
    head = rest.split("-", 1)[0]
    return int(head) if head.isdigit() else None


def sweep_dead_temporaries(cache_root: Path | None = None) -> int:
    """Remove ``/tmp/zcomp-job-<pid>-*``, ``/tmp/zcomp-intrinsics-work-<pid>-*`` and
    ``<cache>/intrinsics/.work-<pid>-*`` whose process is gone."""
    n = 0
    places = [(Path(tempfile.gettempdir()), ("zcomp-job-", "zcomp-intrinsics-work-"))]
    if cache_root is not None:
        places.append((Path(cache_root) / "intrinsics", (".work-",)))
    for folder, prefixes in places:
        try:
            entries = list(folder.iterdir())
        except OSError:
            continue
        for p in entries:
            for prefix in prefixes:
                if not p.name.startswith(prefix):
                    continue
                pid = _pid_of(p.name, prefix)
                if pid is None or pid_alive(pid):
                    continue
                with contextlib.suppress(OSError):
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p)
                    else:
                        p.unlink()
                    n += 1
    return n
