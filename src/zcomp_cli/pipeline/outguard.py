"""Guarding an output folder shared by runs: locks, containment, hashes, litter.

* **Locks** (``fcntl.flock``, released by the kernel when the process dies, even by
  ``kill -9``: a lock left by a dead process is simply taken over). A run registers
  ``OUT/.zcomp-run-<pid>.lock``, naming its manifest and the jobs it selected, under
  ``.zcomp-plan.lock``: two runs (or two ``--shard`` runs) never hold the same job, so
  shards of one manifest write side by side while a second run of the same jobs is
  refused, naming the first one's pid, and a run of *another* manifest into the same
  folder at the same time is refused (its outputs would be mixed in). One descriptor
  per run, whatever the job count. Each job's ``.zcomp-job-<name>.lock`` is held only
  while the job runs (by the process that runs it: this one, or a Ray worker).
  ``.zcomp-summary.lock`` serialises the read-merge-write of ``summary.json``. Lock
  files are removed when released: a finished (or interrupted) run leaves none.
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
import re
import shutil
import tempfile
import threading
import time
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.filedigest import sha256_file
from zcomp_cli.interrupts import deferred
from zcomp_cli.safe_read import read_json_file

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
        """Take the lock; None on success, else what the current holder wrote. Whole or
        not at all: an interrupt waits (a lock file opened but not recorded would stay)."""
        try:
            with deferred():
                return self._try_acquire()
        except BaseException:  # an interrupt held meanwhile: a lock taken is given back
            self.release()
            raise

    def _try_acquire(self) -> dict | None:
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
        with deferred():
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = None


def _read_holder(fd: int) -> dict | None:
    """What the holder of a lock file wrote (a run's lock lists its jobs: it can be long)."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(fd, 1 << 20):
            chunks.append(chunk)
        doc = json.loads(b"".join(chunks).decode() or "null")
        return doc if isinstance(doc, dict) else None
    except (OSError, ValueError):
        return None


@contextlib.contextmanager
def _exclusive(path: Path, what: str, timeout_s: float = 60.0):
    """Hold ``path``'s flock (waiting up to ``timeout_s``) for a short critical section."""
    lock = _FileLock(path, {"pid": os.getpid()})
    deadline = time.monotonic() + timeout_s
    while lock.try_acquire() is not None:
        if time.monotonic() > deadline:
            raise UsageError(f"{path.parent}: another run holds the {what} lock for over {timeout_s:.0f} s")
        time.sleep(0.02)
    try:
        yield
    finally:
        lock.release()


class OutputLock:
    """One run's hold on ``out_root`` (see the module docstring): a single lock file,
    ``.zcomp-run-<pid>.lock``, held (``flock``) for the whole run and naming its
    manifest and the jobs it selected. Registration happens under
    ``.zcomp-plan.lock``: a run whose jobs overlap a live run's, or a run of another
    manifest, is refused. One file descriptor per run, whatever the job count; each
    job's own lock (:func:`job_lock`) is held only while that job runs. Use as a
    context manager, or ``acquire()`` / ``release()``."""

    def __init__(self, out_root: Path, manifest_path: Path, manifest_id: str, job_names: list[str],
                 what: str = "zcomp composite"):
        self.out_root = Path(out_root)
        self.dir = self.out_root
        self.manifest_path = str(manifest_path)
        self.manifest_id = manifest_id
        self.job_names = list(job_names)
        self.what = what
        self._run: _FileLock | None = None

    def _info(self, **extra) -> dict:
        return {"pid": os.getpid(), "command": self.what, "manifest": self.manifest_path,
                "manifest_id": self.manifest_id, "started": time.time(), **extra}

    def acquire(self) -> "OutputLock":
        self.dir.mkdir(parents=True, exist_ok=True)
        try:
            with _exclusive(self.dir / f"{LOCK_PREFIX}plan.lock", "plan"):
                self._check_other_runs()
                run = _FileLock(self.dir / f"{LOCK_PREFIX}run-{os.getpid()}.lock", self._info(jobs=self.job_names))
                if run.try_acquire() is not None:  # our own pid: only a forked copy of us
                    raise UsageError(f"{self.out_root} is already locked by this process")
                self._run = run
            self._sweep_stale_job_locks()
        except BaseException:
            self.release()
            raise
        return self

    def _check_other_runs(self) -> None:
        mine = set(self.job_names)
        for p in sorted(self.dir.glob(f"{LOCK_PREFIX}run-*.lock")):
            if p.name == f"{LOCK_PREFIX}run-{os.getpid()}.lock":
                continue
            probe = _FileLock(p, {})
            holder = probe.try_acquire()
            if holder is None:  # nobody holds it: a dead run's file
                probe.release()
                continue
            pid = holder.get("pid")
            if holder.get("manifest_id") not in (None, self.manifest_id):
                raise UsageError(
                    f"{self.out_root} is being written by another zcomp run (pid {pid}) "
                    f"from another manifest ({holder.get('manifest')}); outputs of two manifests would "
                    "be mixed: wait for it, or use another --out")
            theirs = holder.get("jobs")
            both = sorted(mine & set(theirs)) if isinstance(theirs, list) else sorted(mine)
            if both:
                cmd = holder.get("command")
                raise UsageError(
                    f"job {both[0]!r}{f' and {len(both) - 1} more' if len(both) > 1 else ''} in {self.out_root} "
                    f"is being made by another zcomp run (pid {pid}{', ' + str(cmd) if cmd else ''}); "
                    "wait for it to finish, or use another --out")

    def _sweep_stale_job_locks(self) -> None:
        """Job lock files left by killed runs: removed when nobody holds them (a live
        run's job locks cannot be taken, so they stay)."""
        for p in self.dir.glob(f"{LOCK_PREFIX}job-*.lock"):
            probe = _FileLock(p, {})
            with contextlib.suppress(OSError):
                if probe.try_acquire() is None:
                    probe.release()

    def release(self) -> None:
        release_job_locks(self.out_root)
        if self._run is not None:
            self._run.release()
            self._run = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False


_HELD_JOB_LOCKS: dict[str, "_FileLock"] = {}  # path -> lock, this process's (see job_lock)
_HELD_GUARD = threading.Lock()


def job_lock(out_root: Path, name: str) -> "_FileLock":
    """Take ``OUT/.zcomp-job-<name>.lock`` while job ``name`` runs (release it with
    :func:`release_job_lock`). Raises OutputError naming the holder's pid when another
    process holds it (a Ray worker of a retried unit, say, while the old one still runs)."""
    from zcomp_cli.errors import OutputError

    lk = _FileLock(Path(out_root) / f"{LOCK_PREFIX}job-{name}.lock", {"pid": os.getpid(), "job": name})
    holder = lk.try_acquire()
    if holder is not None:
        raise OutputError(f"job {name!r} is being made by another process (pid {holder.get('pid')})")
    with _HELD_GUARD:
        _HELD_JOB_LOCKS[str(lk.path)] = lk
    return lk


def release_job_lock(lk: "_FileLock | None") -> None:
    if lk is None:
        return
    with _HELD_GUARD:
        _HELD_JOB_LOCKS.pop(str(lk.path), None)
    lk.release()


def release_job_locks(out_root: Path) -> None:
    """Release every job lock this process holds in ``out_root`` (a run that ends,
    also by an interrupt, leaves none)."""
    prefix = str(Path(out_root) / f"{LOCK_PREFIX}job-")
    with _HELD_GUARD:
        mine = [k for k in _HELD_JOB_LOCKS if k.startswith(prefix)]
        locks = [_HELD_JOB_LOCKS.pop(k) for k in mine]
    for lk in locks:
        lk.release()


@contextlib.contextmanager
def held_or_refused(path: Path, what: str):
    """Hold the lock file ``path`` for the block, or refuse (``UsageError`` naming the
    holder's pid) when another live process holds it: for a command whose runs into
    one folder would replace each other's files (``preview-light``)."""
    lock = _FileLock(Path(path), {"pid": os.getpid(), "what": what})
    holder = lock.try_acquire()
    if holder is not None:
        raise UsageError(f"{Path(path).parent}: another {what} (pid {holder.get('pid')}) is writing there; "
                         "wait for it to finish")
    try:
        yield
    finally:
        lock.release()


@contextlib.contextmanager
def summary_lock(out_root: Path, timeout_s: float = 60.0):
    """Serialise read-merge-write of ``summary.json`` between concurrent runs (shards)."""
    with _exclusive(Path(out_root) / f"{LOCK_PREFIX}summary.lock", "summary", timeout_s):
        yield


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
class DigestCache:
    """sha256 of files, remembered by (absolute path, size, mtime_ns)."""

    def __init__(self, store: Path | None):
        self.store = store
        self._data: dict[str, list] = {}
        self._dirty = False
        if store is not None and store.is_file():
            try:
                data = read_json_file(store)
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
        if Path(name).is_absolute() or ".." in Path(name).parts:  # a hostile report: never read outside
            return f"its report names {name!r}, outside the job folder"
        p = job_dir / name
        if not isinstance(rec, dict) or not p.is_file():  # (a FIFO is not a file: never opened)
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


# ``imageio.atomic_path``'s temporary name: ``.<stem>.<pid>-<random>.tmp<ext>``
# (mkstemp's random part has no dot)
_WRITER_TMP = re.compile(r"^\..*\.(\d+)-[^.]*\.tmp")


def clean_dead_writers(folder: Path) -> int:
    """Remove the temporary files (``imageio.atomic_path``) that writers no longer alive
    left in ``folder``, a folder shared by runs side by side (``OUT/lights``): a live
    run's temporary is kept, and so is one whose name does not say its writer."""
    n = 0
    folder = Path(folder)
    if not folder.is_dir() or folder.is_symlink():
        return 0
    for p in folder.iterdir():
        m = _WRITER_TMP.match(p.name)
        if m and p.is_file() and not p.is_symlink() and not pid_alive(int(m.group(1))):
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


def _kept_log(p: Path) -> bool:
    """A Blender log kept on purpose (its batch had a failed item, whose error names it)."""
    from zcomp_cli.blender.runner import KEEP_MARK

    try:
        with open(p, "rb") as f:
            f.seek(max(0, f.seek(0, os.SEEK_END) - 200))
            return KEEP_MARK.encode() in f.read()
    except OSError:
        return True


def sweep_dead_temporaries(cache_root: Path | None = None) -> int:
    """Remove ``/tmp/zcomp-job-<pid>-*``, ``/tmp/zcomp-intrinsics-work-<pid>-*``, the cycles
    renderer's ``/tmp/zcomp-cycles-<pid>-*``, preview-light's ``/tmp/zcomp-preview-<pid>-*``,
    ``<cache>/intrinsics/.work-<pid>-*``, Blender's temporary folders ``/tmp/zcomp-blendertmp-<pid>-*``
    and its logs ``/tmp/zcomp-blender-<pid>-*.log``
    (unless kept on purpose: ``blender.runner.KEEP_MARK``) whose process is gone."""
    from zcomp_cli.blender.runner import LOG_PREFIX, TMP_PREFIX

    n = 0
    places = [(Path(tempfile.gettempdir()), ("zcomp-job-", "zcomp-intrinsics-work-", "zcomp-cycles-",
                                             "zcomp-preview-", LOG_PREFIX, TMP_PREFIX))]
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
                if prefix == LOG_PREFIX and (not p.name.endswith(".log") or _kept_log(p)):
                    continue
                with contextlib.suppress(OSError):
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p)
                    else:
                        p.unlink()
                    n += 1
    return n
