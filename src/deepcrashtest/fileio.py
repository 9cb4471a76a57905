"""Safe file output: write to a temporary file in the same folder, then rename.

Nothing already written is lost: an existing file is only replaced when ``force`` is true,
and a crash mid-write leaves the old file (or nothing) in place, never a half-written one.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

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
    if p.exists() and not force:
        raise UserError(f"{p}: already exists (use --force to overwrite)")
    if not p.parent.exists():
        p.parent.mkdir(parents=True, exist_ok=True)
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], force: bool = False, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    Use this for writers that want a file name (video encoders, matplotlib). On an exception
    the temporary file is removed and ``path`` is left untouched.
    """
    target = check_writable(path, force)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=suffix or target.suffix, dir=target.parent)
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
    if p.stat().st_size == 0:
        raise UserError(f"{p}: {what} is empty")
    return p


def sha256_file(path: str | os.PathLike[str], chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()
