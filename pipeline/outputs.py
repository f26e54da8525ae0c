"""The files `replay --out DIR` writes (../shared/CONTRACT.md), and how every command writes
its outputs: all-or-nothing, whatever stops it.

A single file (a log, a recording, a sweep's table) is written under a temporary name beside
it, flushed to disk and renamed over it. A set of files (a replay's output folder) is written
into a new folder beside DIR, flushed, and swapped with DIR in one rename (Linux's
`renameat2(RENAME_EXCHANGE)`); the old folder is deleted after. A run killed at any instant,
SIGKILL included, leaves DIR holding the complete old set or the complete new set, never a mix.
A set of files in a folder that holds other things too (a sweep's report) is moved into place
together once marked complete (`FileSet`).

A writer holds a lock (flock) on its temporary file or folder while it lives. Whoever next
writes the same target deletes the temporaries whose lock is free: those of runs that died.
A read-only folder (its permissions, not only the system's checks, say so) is not written.

Numbers are written with fixed formats, so the same run gives the same bytes.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import json
import logging
import os
import shutil
import signal
import stat
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any, Self

import numpy as np

from pipeline.errors import InputError
from pipeline.geometry import quaternion_from_rotation

logger = logging.getLogger(__name__)

TRAJECTORY = "trajectory.tum"
LANDMARKS = "landmarks.csv"
ASSOCIATIONS = "associations.csv"
METRICS = "metrics.json"

PART = ".part"  # a temporary file: .NAME.RANDOM.part beside NAME
STAGING = ".staging"  # a temporary folder: .NAME.RANDOM.staging beside NAME

# Test seam: called with the name of each step of a write as it completes, so that a test can
# stop the process between any two steps (tests/test_outputs.py kills it there).
step_hook: Callable[[str], None] | None = None


def _step(name: str) -> None:
    if step_hook is not None:
        step_hook(name)


# ------------------------------------------------------------------------------ formats


def stamp_text(stamp_ns: int) -> str:
    """Integer nanoseconds as seconds with nine decimals, exactly: a float holds an epoch stamp
    (1.4e18 ns) to about 0.2 µs only."""
    seconds, nanoseconds = divmod(int(stamp_ns), 10**9)
    return f"{seconds}.{nanoseconds:09d}"


def trajectory_tum(stamps_ns: Iterable[int], poses: Iterable[np.ndarray]) -> str:
    """evo's TUM format: `stamp tx ty tz qx qy qz qw`, a line a pose, the stamp in seconds."""
    lines = []
    for stamp, T in zip(stamps_ns, poses, strict=True):
        q = quaternion_from_rotation(T[:3, :3])
        values = [*T[:3, 3], *q]
        lines.append(" ".join([stamp_text(stamp), *(f"{v:.9f}" for v in values)]))
    return "\n".join(lines) + "\n"


def landmarks_csv(rows: Iterable[tuple[int, np.ndarray, int, float, int]]) -> str:
    lines = ["id,x,y,z,class_id,class_probability,observations"]
    for landmark_id, position, class_id, probability, observations in rows:
        x, y, z = position
        lines.append(
            f"{landmark_id},{x:.6f},{y:.6f},{z:.6f},{class_id},{probability:.6f},{observations}"
        )
    return "\n".join(lines) + "\n"


def associations_csv(rows: Iterable[tuple[int, int, int, float]]) -> str:
    lines = ["pose_index,detection_index,landmark_id,weight"]
    lines += [f"{p},{d},{lm},{w:.6f}" for p, d, lm, w in rows]
    return "\n".join(lines) + "\n"


def metrics_json(metrics: dict) -> str:
    return json.dumps(metrics, indent=2, sort_keys=True) + "\n"


# ---------------------------------------------------------------------- the file system


def _default_mode(kind: int) -> int:
    """What a new file (0o666) or folder (0o777) gets under this process's umask."""
    umask = os.umask(0)
    os.umask(umask)
    return kind & ~umask


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _named(exc: OSError, path: Path) -> OSError:
    """`exc` naming `path` (a failed write() or fsync() names no file)."""
    return exc if exc.filename else OSError(exc.errno, exc.strerror, str(path))


def _is_leftover(name: str, target: str) -> bool:
    return name.startswith(f".{target}.") and name.endswith((PART, STAGING))


def remove_tree(path: Path) -> None:
    """Delete the folder `path` and all it holds, read-only subfolders included (a staging
    copy of a read-only folder); what cannot be deleted is left."""
    with contextlib.suppress(OSError):
        os.chmod(path, 0o700)
    for folder, inside, _ in os.walk(path):  # top down: a folder is opened after this
        for name in inside:
            if not os.path.islink(entry := os.path.join(folder, name)):
                with contextlib.suppress(OSError):
                    os.chmod(entry, 0o700)
    shutil.rmtree(path, ignore_errors=True)


def refuse_read_only(folder: Path, given: str | os.PathLike) -> None:
    """An `InputError` if the existing folder `folder` is read-only (no write permission for
    anyone, or none for this user): its permissions say not to write there, and even a
    process allowed to (root) does not."""
    try:
        mode = folder.stat().st_mode
    except OSError:
        return  # not there (yet): whoever makes it says what is wrong
    if stat.S_ISDIR(mode) and (mode & 0o222 == 0 or not os.access(folder, os.W_OK)):
        where = "" if Path(given).resolve() == folder.resolve() else f"its folder {folder} is "
        raise InputError(
            f"{given}: {where}a read-only folder (mode {stat.S_IMODE(mode):o}); not writing there"
        )


def clean_leftovers(target: Path) -> None:
    """Delete the temporaries that dead writers of `target` left beside it."""
    try:
        names = [n for n in os.listdir(target.parent) if _is_leftover(n, target.name)]
    except OSError:
        return
    for name in names:
        path = target.parent / name
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # its writer is alive
            os.close(fd)
            continue
        try:
            if path.is_dir():
                remove_tree(path)
            else:
                path.unlink(missing_ok=True)
            logger.info("removed %s, left by a run that did not finish", path)
        finally:
            os.close(fd)


def _cannot_write(path: Path, exc: OSError) -> InputError:
    detail = exc.strerror or type(exc).__name__
    if exc.filename is not None and Path(exc.filename) != path:
        detail += f": {exc.filename}"
    return InputError(f"{path}: cannot write there ({detail})")


def atomic_output(path: Path) -> tuple[int, Path]:
    """A new temporary file beside `path` (fd, its path), locked while the fd is open, to be
    renamed onto `path` once complete; first, dead writers' temporaries are removed."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory")
    refuse_read_only(path.parent, path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=PART, dir=path.parent)
    fcntl.flock(fd, fcntl.LOCK_EX)
    os.fchmod(fd, _default_mode(0o666))  # mkstemp makes 0600; the result is like any new file
    return fd, Path(tmp)


class AtomicFile:
    """A file at `path` that appears complete or not at all. As a context manager it commits
    when the block ends normally and discards the temporary on an exception."""

    def __init__(self, path: str | os.PathLike, mode: str = "wb", **open_args: Any):
        self.path = Path(path)
        try:
            fd, self.temporary = atomic_output(self.path)
        except OSError as exc:
            raise _cannot_write(self.path, exc) from None
        self.file: IO = os.fdopen(fd, mode, **open_args)

    def commit(self) -> None:
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            _step(f"wrote {self.path.name}")
            os.replace(self.temporary, self.path)  # before the lock goes: no cleaner takes it
        except BaseException as exc:
            self.discard()
            if isinstance(exc, OSError):  # named by the target, not by the temporary
                raise OSError(exc.errno, exc.strerror, str(self.path)) from None
            raise
        self.file.close()
        _fsync_dir(self.path.parent)
        _step(f"renamed {self.path.name}")

    def discard(self) -> None:
        self.file.close()
        self.temporary.unlink(missing_ok=True)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


def write_text(path: Path, text: str) -> None:
    """Write `text` to `path` all-or-nothing."""
    with AtomicFile(path, "w", encoding="utf-8", newline="") as out:
        out.file.write(text)


# ------------------------------------------------------------------- folders of outputs

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2() -> Any:
    try:
        function = ctypes.CDLL(None, use_errno=True).renameat2
    except AttributeError:  # not glibc >= 2.28
        return None
    function.argtypes = [
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_uint,
    ]
    return function


_renameat2_function = _renameat2()


def exchange(a: Path, b: Path) -> bool:
    """Swap the paths `a` and `b` in one step; False where the system cannot."""
    if _renameat2_function is None:
        return False
    done = _renameat2_function(
        _AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE
    )
    if done == 0:
        return True
    error = ctypes.get_errno()
    if error in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(error, os.strerror(error), str(b))


def _subfolder(folder: Path) -> str | None:
    """The name of a folder inside `folder`, if it holds one."""
    with os.scandir(folder) as entries:
        return next((e.name for e in entries if e.is_dir(follow_symlinks=False)), None)


def _output_folder(path: str | os.PathLike, nested: bool) -> Path:
    """`path` as an output folder that can be replaced whole, or an InputError saying why not."""
    target = Path(path).resolve()
    if target.exists() and not target.is_dir():
        raise InputError(f"{path}: exists and is not a directory")
    cwd = Path.cwd().resolve()
    if target == cwd or target in cwd.parents:
        raise InputError(f"{path}: holds the current directory; choose a folder of its own")
    refuse_read_only(target, path)
    refuse_read_only(target.parent, path)
    if target.is_dir() and not nested:
        inside = _subfolder(target)
        if inside is not None:
            raise InputError(
                f"{path}: holds the folder {inside!r}; an output folder is replaced whole, so it "
                "may hold files only"
            )
    return target


class _Staged:
    """Outputs written into a staging folder first (`.NAME.RANDOM.staging` beside the target),
    which is locked (flock) while its writer lives. As a context manager, the staging folder
    is discarded on leaving the block unless the subclass's `commit` unlocked it."""

    staging: Path
    _lock: int | None

    def _stage(self, target: Path, given: Path) -> None:
        """Delete what dead writers of `target` left, and make the staging folder."""
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            clean_leftovers(target)
            self.staging = Path(
                tempfile.mkdtemp(prefix=f".{target.name}.", suffix=STAGING, dir=target.parent)
            )
        except OSError as exc:
            raise _cannot_write(given, exc) from None
        self._lock = os.open(self.staging, os.O_RDONLY | os.O_DIRECTORY)
        fcntl.flock(self._lock, fcntl.LOCK_EX)

    def _unlock(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None

    def discard(self) -> None:
        if self._lock is not None:
            remove_tree(self.staging)
            self._unlock()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info) -> None:
        self.discard()


class OutputFolder(_Staged):
    """A new version of the output folder `path`, complete or not at all. Files go into a
    staging folder beside it, which `commit` swaps with `path` in one rename. Files already in
    `path` that the new set does not write (nor names stale) are kept. As a context manager it
    discards the staging folder unless `commit` ran.

    A `nested` folder may hold folders (`mmslam compare`'s, a folder per method): what is
    written into `staging` goes in whole, and the old folder's other entries are kept."""

    def __init__(self, path: str | os.PathLike, nested: bool = False):
        self.given = Path(path)
        self.nested = nested
        self.path = _output_folder(path, nested)
        self._stage(self.path, self.given)

    def commit(self, files: dict[str, str | bytes], stale: Iterable[str] = ()) -> None:
        """Swap in the set `files` (name -> content), keeping other files already in the
        folder except those named in `stale`."""
        written = set(files) | set(stale)
        for name, content in files.items():
            self._write(name, content)
        mode = _default_mode(0o777)
        exists = self.path.is_dir()
        if exists:
            self._carry_over(written)
            mode = self.path.stat().st_mode & 0o7777
        os.chmod(self.staging, mode)
        _fsync_dir(self.staging)
        _step("staged")
        if not exists:
            try:
                os.rename(self.staging, self.path)
            except OSError as exc:  # made meanwhile by another run
                if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
                exists = True
        if exists and not exchange(self.staging, self.path):
            logger.warning("%s: no atomic exchange on this file system; renaming twice", self.path)
            aside = self.staging.with_name(self.staging.name[: -len(STAGING)] + ".old" + STAGING)
            os.rename(self.path, aside)
            os.rename(self.staging, self.path)
            os.rename(aside, self.staging)
        _fsync_dir(self.path.parent)
        _step("swapped")
        remove_tree(self.staging)  # the old set
        self._unlock()
        _step("removed the old set")

    def _write(self, name: str, content: str | bytes) -> None:
        if not name or os.sep in name or name in (".", ".."):
            raise ValueError(f"not a file name: {name!r}")
        path = self.staging / name
        data = content.encode("utf-8") if isinstance(content, str) else content
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        except OSError as exc:
            raise _named(exc, self.given / name) from None
        finally:
            os.close(fd)
        _step(f"wrote {name}")

    def _carry_over(self, written: set[str]) -> None:
        """Hard-link the old folder's other entries into the new one (copy where links fail)."""
        if not self.nested and (inside := _subfolder(self.path)) is not None:
            raise InputError(f"{self.given}: a folder {inside!r} appeared in it; not replacing it")
        written |= set(os.listdir(self.staging))  # what the new set holds already
        for name in os.listdir(self.path):
            old_temporary = any(_is_leftover(name, w) for w in written)
            if name in written or old_temporary:
                continue
            source, target = self.path / name, self.staging / name
            if source.is_dir() and not source.is_symlink():
                shutil.copytree(source, target, symlinks=True, copy_function=_link_or_copy)
            else:
                _link_or_copy(source, target)


# ------------------------------------------------------- sets of files among other things

COMMIT = ".commit"  # a staged set marked complete: .NAME.RANDOM.commit, being moved into place


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM wait (in the main thread, where Python handles
    them): the block's renames are not cut short; the first signal is raised after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    wanted = (signal.SIGINT, signal.SIGTERM)
    previous = {number: signal.signal(number, lambda n, _: caught.append(n)) for number in wanted}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        if caught:
            signal.raise_signal(caught[0])


@contextlib.contextmanager
def _folder_locked(folder: Path) -> Iterator[None]:
    """An exclusive lock on the folder itself (flock on its descriptor), while a set moves."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _move_into_place(marked: Path, folder: Path) -> None:
    for name in sorted(os.listdir(marked)):
        os.replace(marked / name, folder / name)
        _step(f"moved {name}")
    _fsync_dir(folder)
    os.rmdir(marked)


def _complete_marked(folder: Path, name: str) -> None:
    """Move into place the sets `name` that writers marked complete and were stopped moving
    (the caller holds the folder's lock)."""
    for entry in sorted(os.listdir(folder)):
        if entry.startswith(f".{name}.") and entry.endswith(COMMIT):
            logger.info("%s: completing the set a stopped run left", folder / entry)
            _move_into_place(folder / entry, folder)


class FileSet(_Staged):
    """Files that replace their earlier versions in `folder` together, all or nothing, where
    the folder holds other things too (a sweep's report beside its runs), so that it cannot be
    swapped whole as `OutputFolder` swaps a replay's.

    The files are written into a staging folder inside `folder` (`path(name)` says where).
    `commit` marks the set complete in one rename (`.NAME.RANDOM.staging` to
    `.NAME.RANDOM.commit`) and then moves its files into place, with SIGINT and SIGTERM held
    back meanwhile. Stopped before the mark, the old set stays (the next writer deletes the
    staging folder); stopped after it (SIGKILL, a power cut), the next `FileSet` of the folder,
    or `recover`, moves the rest of the marked set into place before anything else. As a
    context manager it discards the staging folder unless `commit` ran."""

    def __init__(self, folder: str | os.PathLike, name: str):
        self.folder, self.name = Path(folder), name
        refuse_read_only(self.folder, self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.recover(self.folder, name)
        except OSError as exc:
            raise _cannot_write(self.folder, exc) from None
        self._stage(self.folder / name, self.folder)

    @staticmethod
    def recover(folder: Path, name: str) -> None:
        """Move into place what a writer of the set `name` marked complete and did not finish
        moving (it was killed meanwhile)."""
        with _folder_locked(folder):
            _complete_marked(folder, name)

    def path(self, name: str) -> Path:
        """Where the file `name` of the set is written before `commit`."""
        return self.staging / name

    def commit(self) -> None:
        _fsync_dir(self.staging)
        _step("staged")
        marked = self.staging.with_name(self.staging.name[: -len(STAGING)] + COMMIT)
        with _signals_held(), _folder_locked(self.folder):
            _complete_marked(self.folder, self.name)  # first, one a killed writer marked
            os.rename(self.staging, marked)
            _fsync_dir(self.folder)
            _step("marked")
            _move_into_place(marked, self.folder)
            self._unlock()
        _step("committed")


def _link_or_copy(source: str | os.PathLike, target: str | os.PathLike) -> None:
    try:
        os.link(source, target, follow_symlinks=False)
    except OSError:
        shutil.copy2(source, target, follow_symlinks=False)


def write_outputs(
    out_dir: str | os.PathLike, files: dict[str, str], stale: Iterable[str] = ()
) -> None:
    """Replace the output set in `out_dir` with `files`, all or nothing (see `OutputFolder`)."""
    with OutputFolder(out_dir) as folder:
        folder.commit(files, stale)
