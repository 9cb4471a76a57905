"""Safe file output: write to a temporary file (or folder) beside the target, then rename.

Nothing already written is lost: an existing file is only replaced when ``force`` is true,
and a crash mid-write leaves the old file (or nothing) in place, never a half-written one.
A command that writes several files into a folder writes them as one set (:func:`output_set`):
the folder holds the complete set of one run, or the command's files are absent. Temporary names
carry the writer's process id, so the leftovers of a killed run are removed by the next run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from deepcrashtest.errors import UserError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(path: str | os.PathLike[str], force: bool = False) -> Path:
    """Return ``path`` as a Path after checking that writing it will not destroy anything unasked."""
    p = Path(path)
    if p.exists() and p.is_dir():
        raise UserError(f"{p}: is a directory, expected a file path")
    if p.exists() and not stat.S_ISREG(p.stat().st_mode):  # renaming onto /dev/null would replace the device
        raise UserError(f"{p}: not a regular file (a device, FIFO or socket), expected a file path to write")
    if p.exists() and not force:
        raise UserError(f"{p}: already exists (use --force to overwrite)")
    if p.parent.exists() and not p.parent.is_dir():
        raise UserError(f"{p.parent}: exists and is not a directory")
    return p  # missing parent folders are made when the file is written (atomic_path), not before the work


def check_not_input(output: str | os.PathLike[str], *inputs: str | os.PathLike[str] | None) -> None:
    """Refuse an output path that is one of the command's input files (``--force`` or not: the output would
    replace what it is made from)."""
    out = Path(output)
    for item in inputs:
        if item is not None and out.exists() and Path(item).exists() and os.path.samefile(out, item):
            raise UserError(f"{out}: is also an input of this command; write the output to another path")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], force: bool = False, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    Use this for writers that want a file name (video encoders, matplotlib). On an exception
    the temporary file is removed and ``path`` is left untouched.
    """
    target = check_writable(path, force)
    _make_parents(target.parent)
    prefix = f".{target.name}.{os.getpid()}."
    _sweep_stale(target.parent, f".{target.name}.", legacy=True)
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix or target.suffix, dir=target.parent)
    except OSError as exc:
        raise UserError(f"{target}: cannot write ({exc.strerror or exc})") from None
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, force: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (temp file + fsync + rename)."""
    with atomic_path(path, force) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str, force: bool = False) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"), force)


def ensure_output_dir(path: str | os.PathLike[str]) -> Path:
    """Create an output directory (and parents); refuse a path that is an existing file."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UserError(f"{p}: exists and is not a directory")
    p.mkdir(parents=True, exist_ok=True)
    return p


def require_file(path: str | os.PathLike[str], what: str = "file") -> Path:
    """Return ``path`` if it is a readable, non-empty regular file, else raise a one-line UserError."""
    p = Path(path)
    if not p.exists():
        raise UserError(f"{p}: no such {what}")
    if p.is_dir():
        raise UserError(f"{p}: is a directory, expected a {what}")
    if not stat.S_ISREG(p.stat().st_mode):  # FIFO, device (/dev/zero), socket: never a user's file
        raise UserError(f"{p}: not a regular file, expected a {what}")
    if p.stat().st_size == 0:
        raise UserError(f"{p}: {what} is empty")
    if not os.access(p, os.R_OK):
        raise UserError(f"{p}: {what} is not readable (permission denied)")
    return p


def read_json(path: Path) -> Any:
    """The JSON value in the file ``path`` (UTF-8; the caller checks it exists with :func:`require_file`); a
    file that is not JSON is a one-line UserError naming it."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a JSON file ({exc})") from None


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


# --------------------------------------------------------------------------- output sets
STAGING_SUFFIX = ".partial"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def _sweep_stale(folder: Path, prefix: str, legacy: bool = False) -> None:
    """Remove ``prefix<pid>.*`` temporary files/folders in ``folder`` whose writer process is gone.

    ``legacy``: also remove ``prefix<random>.*`` (temporary names without a process id, as older versions
    wrote them).
    """
    try:
        entries = list(folder.iterdir()) if folder.is_dir() else []
    except OSError:
        return
    for entry in entries:
        if not entry.name.startswith(prefix):
            continue
        pid = entry.name[len(prefix) :].split(".", 1)[0]
        if pid.isdigit() and (int(pid) == os.getpid() or _pid_alive(int(pid))):
            continue
        if not pid.isdigit() and not legacy:
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and missing parents; return the ones created (deepest first)."""
    created: list[Path] = []
    p = folder
    while not p.exists() and p != p.parent:
        created.append(p)
        p = p.parent
    if p.exists() and not p.is_dir():
        raise UserError(f"{p}: exists and is not a directory")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{folder}: cannot create the folder ({exc.strerror or exc})") from None
    return created


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


@contextlib.contextmanager
def output_set(target: str | os.PathLike[str], names: Iterable[str], force: bool = False) -> Iterator[Path]:
    """Write a command's whole output set into a staging folder beside ``target``; move it in at the end.

    ``names`` are every file or folder name the command may write into ``target``. Refused before any
    work when ``target`` is a file, or holds one of ``names`` and ``force`` is false. Yields the staging
    folder (write there under the final names). On success the set replaces the previous run's: names of
    ``names`` the new run did not write are removed, so ``target`` never mixes two runs; other files in
    ``target`` are kept. When ``target`` did not exist the staging folder is renamed onto it in one step.
    On an error nothing is moved: the staging folder and any parent folders this call created are removed,
    so a failed run leaves no empty folder behind.
    """
    out = Path(os.path.abspath(target))
    own = set(names)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a directory")
    if out.is_dir() and not force:
        taken = sorted(n for n in own if (out / n).exists() or (out / n).is_symlink())
        if taken:
            raise UserError(f"{out / taken[0]}: already exists (use --force to overwrite)")
    created = _make_parents(out.parent)
    _sweep_stale(out.parent, f".{out.name}.")
    if out.is_dir():
        for name in own:
            _sweep_stale(out, f".{name}.", legacy=True)
    try:
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.{os.getpid()}.", suffix=STAGING_SUFFIX, dir=out.parent))
    except OSError as exc:
        for p in created:
            with contextlib.suppress(OSError):
                p.rmdir()
        raise UserError(f"{out}: cannot write ({exc.strerror or exc})") from None
    os.chmod(stage, 0o777 & ~_umask())
    try:
        yield stage
        _commit(stage, out, own)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        for p in created:
            with contextlib.suppress(OSError):
                p.rmdir()
        raise


def _commit(stage: Path, out: Path, own: set[str]) -> None:
    """Move the staged set onto ``out`` (see :func:`output_set`)."""
    if not out.exists():
        os.rename(stage, out)
        return
    new = {p.name for p in stage.iterdir()}
    for name in own - new:  # the previous run's files this run did not make
        _remove(out / name)
    for name in sorted(new):
        if (out / name).is_dir() and not (out / name).is_symlink():
            shutil.rmtree(out / name)
        os.replace(stage / name, out / name)
    stage.rmdir()


def restage_paths(value: Any, stage: Path, out: Path) -> Any:
    """Paths (strings) under a staging folder -> the same paths under the output folder, recursively."""
    if isinstance(value, str) and value.startswith(str(stage)):
        return str(out / Path(value).relative_to(stage))
    if isinstance(value, list):
        return [restage_paths(v, stage, out) for v in value]
    if isinstance(value, dict):
        return {k: restage_paths(v, stage, out) for k, v in value.items()}
    return value
