"""Write a file so that it is either complete or untouched: no half-written outputs.

Also the checks a command makes on its outputs before any work (:func:`check_output`,
:func:`check_folder_output`), and groups of files that are put in place together or not at
all (:class:`StagedFiles`).
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import stat
import tempfile
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

from . import _interrupt
from ._errors import InputError


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``path`` atomically: see
    :func:`write_bytes_atomic`."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and ``os.replace``.

    An existing file keeps its permissions; a new one gets the umask's. The temporary file
    never survives, whatever fails.
    """
    path = real_target(path)
    tmp = _write_temp(path, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        _unlink(tmp)
        raise
    _fsync_folder(path.parent)


def real_target(path: str | Path) -> Path:
    """Where a write to ``path`` lands: a symbolic link's target (so the file the link names
    gets the new contents, and the link stays a link), else ``path`` itself; ``OSError`` for
    a loop of links."""
    real = Path(os.path.realpath(path))
    if real.is_symlink():  # realpath gives up on a loop
        raise OSError(errno.ELOOP, os.strerror(errno.ELOOP), str(path))
    return real


def _write_temp(path: Path, data: bytes) -> str:
    """``data`` in a new temporary file beside ``path``, with ``path``'s permissions."""
    _interrupt.before_writing()  # Ctrl-C before the first output: nothing is written
    sweep_stale(path)
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, mode)  # mkstemp makes 0600; give the file the usual permissions
    except BaseException:
        _unlink(tmp)
        raise
    return tmp


# -- temporary files left behind -------------------------------------------------------------

#: A temporary file of ours this old is stale whoever made it (a process on another machine
#: sharing the folder, or one whose number was reused), s.
STALE_AFTER_S = 3600.0
#: One whose process has ended is stale once this old (a process on another machine with the
#: same number may still be writing it for a moment), s.
ORPHAN_AFTER_S = 10.0


def _temp_prefix(path: Path) -> str:
    # The writer's process number in the name tells a leftover from a write in progress.
    return f".{path.name}.{os.getpid()}."


def sweep_stale(path: Path) -> list[str]:
    """Remove the temporary files of earlier writes to ``path`` that a killed process left
    beside it (``.NAME.PID.XXXXXXXX.tmp``, ``.old`` or ``.probe``, and the older
    ``.NAME.XXXXXXXX.tmp`` without a process number): only names of this module's making,
    only stale ones (their process has ended, :data:`ORPHAN_AFTER_S`; or older than
    :data:`STALE_AFTER_S`). Returns the names removed; what cannot be removed is left."""
    ours = re.compile(rf"\.{re.escape(path.name)}\.(?:(\d+)\.)?[a-z0-9_]{{8}}\.(?:tmp|old|probe)")
    removed = []
    now = time.time()
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        match = ours.fullmatch(entry.name)
        if not match:
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            age = now - entry.stat(follow_symlinks=False).st_mtime
            pid = match.group(1)
            if age > STALE_AFTER_S or (pid and age > ORPHAN_AFTER_S and not _alive(int(pid))):
                os.unlink(entry.path)
                removed.append(entry.name)
        except OSError:
            continue
    return removed


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (unknown counts as running)."""
    if pid == os.getpid() or os.name == "nt":  # Windows' os.kill(pid, 0) would signal it
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def _unlink(path: str | Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _fsync_folder(folder: Path) -> None:
    try:  # make the rename itself durable; not possible everywhere
        dir_fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)


_UMASK: list[int] = []


def _umask() -> int:
    if not _UMASK:
        current = os.umask(0o022)
        os.umask(current)
        _UMASK.append(current)
    return _UMASK[0]


# -- checks before the work ------------------------------------------------------------------


def reason(e: OSError) -> str:
    """An OSError's reason without the file names in it (they may be temporary files)."""
    return e.strerror or type(e).__name__


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name the same file (links and ``..`` followed)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return Path(a).resolve() == Path(b).resolve()


def _check_target(path: Path, field: str, inputs: Iterable[str | Path | None]) -> None:
    if path.is_dir():
        raise InputError(path, field, "cannot write: is a folder")
    if path.exists() and not path.is_file():
        raise InputError(path, field, "cannot write: not a regular file")
    for other in inputs:
        if other is not None and same_file(path, other):
            raise InputError(path, field, f"is the input {str(other)!r}: writing it would "
                             "destroy it; choose another file")  # fmt: skip


def _probe(folder: Path, path: Path, field: str) -> None:
    """Create and remove a file in ``folder``, as the atomic write will."""
    probe = folder / "handeye-jax"
    sweep_stale(probe)
    try:
        fd, tmp = tempfile.mkstemp(prefix=_temp_prefix(probe), suffix=".probe", dir=folder)
    except OSError as e:
        why = f"cannot write in folder {str(folder)!r}: {reason(e)}"
        raise InputError(path, field, why) from None
    os.close(fd)
    _unlink(tmp)


def check_output(
    path: str | Path, field: str = "", inputs: Iterable[str | Path | None] = ()
) -> Path:
    """Refuse an output file that cannot be written, before the work that makes it.

    Raises :class:`InputError` naming ``path`` and ``field`` (e.g. ``"--out"``) if its folder
    is missing or not writable, if it is a folder or not a regular file, or if it is the same
    file as one of ``inputs``.
    """
    path = Path(path)
    try:
        folder = real_target(path).parent  # a symbolic link is written through
        if not folder.is_dir():
            what = "is not a folder" if folder.exists() else "does not exist"
            raise InputError(path, field, f"cannot write: folder {str(folder)!r} {what}")
        _check_target(path, field, inputs)
    except OSError as e:
        raise InputError(path, field, f"cannot write: {reason(e)}") from None
    _probe(folder, path, field)
    return path


def check_folder_output(
    folder: str | Path,
    names: Iterable[str],
    field: str = "",
    inputs: Iterable[str | Path | None] = (),
) -> list[Path]:
    """:func:`check_output` for files ``names`` in ``folder`` (created later if missing).

    Returns the files' paths. Messages about the folder itself name ``folder``, the rest
    the file.
    """
    folder = Path(folder)
    inputs = list(inputs)
    paths = [folder / name for name in names]
    try:
        if folder.exists() and not folder.is_dir():
            raise InputError(folder, field, "cannot write: is a file, not a folder")
        if not folder.parent.is_dir():
            what = "is not a folder" if folder.parent.exists() else "does not exist"
            raise InputError(folder, field, f"cannot write: folder {str(folder.parent)!r} {what}")
        exists = folder.is_dir()
        for path in paths if exists else ():
            _check_target(path, field, inputs)
    except OSError as e:
        raise InputError(folder, field, f"cannot write: {reason(e)}") from None
    _probe(folder if exists else folder.parent, folder, field)
    return paths


# -- several files at once ---------------------------------------------------------------------


class StagedFiles:
    """Files written to temporary names beside their targets, then put in place together.

    :meth:`commit` replaces every target; if one fails, those already replaced get their
    previous contents back. Until then (and after :meth:`discard`) no target is touched.
    An OSError becomes an :class:`InputError` naming the target and ``field``.
    """

    def __init__(self, files: Mapping[str | Path, bytes], field: str = ""):
        self.field = field
        self._temps: dict[Path, str] = {}
        self._real: dict[Path, Path] = {}  # each target, through a symbolic link
        path = None
        try:
            for path, data in files.items():
                path = Path(path)
                _check_target(path, field, ())
                self._real[path] = real_target(path)
                self._temps[path] = _write_temp(self._real[path], data)
        except BaseException as e:
            self.discard()
            if isinstance(e, OSError):
                raise InputError(path, field, f"cannot write: {reason(e)}") from None
            raise

    @property
    def paths(self) -> list[Path]:
        return list(self._temps)

    def discard(self) -> None:
        """Remove the temporary files; the targets stay as they were."""
        for tmp in self._temps.values():
            try:
                _unlink(tmp)
            except OSError:
                pass
        self._temps = {}

    def commit(self) -> list[Path]:
        """Put every file in place (all or, on failure, none); returns their paths."""
        previous: dict[Path, str] = {}  # target -> a link to (or copy of) what it held
        done: list[Path] = []
        path = None
        real = self._real
        try:
            for path in self._temps:
                if real[path].exists():
                    previous[path] = _keep(real[path])
            for path, tmp in self._temps.items():
                os.replace(tmp, real[path])
                done.append(path)
        except BaseException as e:
            for p in reversed(done):
                try:
                    if p in previous:
                        os.replace(previous.pop(p), real[p])
                    else:
                        os.unlink(real[p])
                except OSError:
                    pass
            self._cleanup(previous)
            self.discard()
            if isinstance(e, OSError):
                raise InputError(path, self.field, f"cannot write: {reason(e)}") from None
            raise
        self._cleanup(previous)
        paths = list(self._temps)
        self._temps = {}
        for folder in {real[p].parent for p in paths}:
            _fsync_folder(folder)
        return paths

    @staticmethod
    def _cleanup(previous: dict[Path, str]) -> None:
        for kept in previous.values():
            try:
                _unlink(kept)
            except OSError:
                pass


def _keep(path: Path) -> str:
    """A hard link to ``path`` (a copy where links are not possible) beside it."""
    while True:
        kept = str(path.with_name(f"{_temp_prefix(path)}{secrets.token_hex(4)}.old"))
        try:
            os.link(path, kept)
            return kept
        except FileExistsError:
            continue
        except OSError:
            fd, kept = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=".old", dir=path.parent)
            os.close(fd)
            shutil.copy2(path, kept)
            return kept


def write_folder_atomic(
    folder: str | Path, files: Mapping[str, bytes], field: str = ""
) -> list[Path]:
    """Write ``files`` (name: bytes) into ``folder`` (created if missing) all or none.

    On failure the folder is as it was (and removed again if this made it); raises
    :class:`InputError` naming the file and ``field``.
    """
    folder = Path(folder)
    made = False
    _interrupt.before_writing()
    if not folder.is_dir():
        try:
            folder.mkdir()
        except OSError as e:
            raise InputError(folder, field, f"cannot write: {reason(e)}") from None
        made = True
    try:
        return StagedFiles({folder / n: d for n, d in files.items()}, field).commit()
    except BaseException:
        if made:
            try:
                folder.rmdir()
            except OSError:
                pass
        raise


def write_output(path: str | Path, data: str | bytes, field: str = "") -> None:
    """:func:`write_bytes_atomic` (text as UTF-8), an OSError raised as an :class:`InputError`
    naming ``path`` and ``field`` (not the temporary file)."""
    try:
        write_bytes_atomic(path, data.encode("utf-8") if isinstance(data, str) else data)
    except OSError as e:
        raise InputError(path, field, f"cannot write: {reason(e)}") from None
