"""Safe output paths: every file the application writes goes through here.

Two steps, so a bad output path fails before an hour of work instead of after it,
and an output never destroys an input or a special file:

- :func:`check_output`, before the run: the path is not empty, not a directory, not
  one of the run's inputs; its directory exists and is writable; an existing file is
  refused or replaced as the output kind's policy says (:data:`REFUSE`, :data:`WARN`).
- :func:`atomic_output` (a context manager yielding the path to write) and
  :func:`atomic_write`, while writing: a regular file is written to a temporary file
  with an unpredictable name in the target directory (``tempfile.mkstemp``, so a
  planted symlink at a guessable ``.part`` name cannot redirect it), then moved over
  the target with ``os.replace``: a reader never sees half a file, and a failure
  (a full disk) leaves the old file, no ``.part``, and one line. A special file
  (``/dev/null``, ``/dev/full``, a FIFO) is written in place: renaming over it would
  replace the device with a regular file.

Policy for an existing file (written in docs/bench-file.md, "Outputs"): recordings and
simulated data (``--record``, ``simulate --out``) are refused without ``--force``: they
are the raw data, often hours of it, and cannot be made again. Documents derived from
them (``--json``, ``report --out``, ``export --out``, ``orders --out``) are replaced with
one line on stderr saying so, since a rerun of the command rebuilds them.
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Literal, TextIO

from ptinertia.errors import UsageError

Policy = Literal["refuse", "warn"]
REFUSE: Policy = "refuse"  # raw data: an existing file needs --force
WARN: Policy = "warn"  # derived documents: replaced, with one line saying so

# errors of the disk, not of the path: reported as "cannot write", not as a bug
_WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO, errno.EACCES}


def is_special(path: Path) -> bool:
    """True for an existing path that is neither a regular file nor a directory
    (a character device, a FIFO, a socket): written in place, never replaced."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(
    path: str | Path,
    option: str,
    inputs: Iterable[str | Path] = (),
    force: bool = False,
    policy: Policy = WARN,
    err: TextIO | None = None,
) -> Path:
    """``path`` as a :class:`Path` once it is safe to write; :class:`UsageError` otherwise.

    ``option`` names the output in the message (``--json``); ``inputs`` are the files the
    run reads (an output equal to one of them is refused, even with ``force``).
    """
    if str(path).strip() == "":
        raise UsageError(f"{option}: empty path")
    out = Path(path)
    for source in inputs:
        src = Path(source)
        if _same_file(out, src) or out.resolve() == src.resolve():
            raise UsageError(
                f"{option} {out}: is an input of this run ({src}); choose another path"
            )
    if out.is_dir():
        raise UsageError(f"{option} {out}: is a directory, expected a file path")
    if is_special(out):
        if not os.access(out, os.W_OK):
            raise UsageError(f"{option} {out}: not writable")
        return out
    parent = out.parent
    if not parent.is_dir():
        raise UsageError(f"{option} {out}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {out}: directory {parent} is not writable")
    if out.exists() and not force:
        if policy == REFUSE:
            raise UsageError(f"{option} {out}: exists; add --force to overwrite it")
        print(f"ptinertia: {option} {out}: exists, overwriting it", file=err or sys.stderr)
    return out


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_error(path: Path, error: OSError) -> UsageError:
    """The one line for a disk error while writing ``path``."""
    return UsageError(f"cannot write {path}: {error.strerror or error}")


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield the path to write instead of ``path``; on success it replaces ``path``.

    A special file is yielded as it is (written in place). A disk error while
    writing becomes one :class:`UsageError` line, and the temporary file is removed.
    """
    out = Path(path)
    if is_special(out):
        try:
            yield out
        except OSError as error:
            if error.errno in _WRITE_ERRNOS:
                raise write_error(out, error) from None
            raise
        return
    target = out.resolve() if out.is_symlink() else out  # update what the link points to
    try:
        fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    except OSError as error:
        raise write_error(out, error) from None
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open would
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except OSError as error:
        tmp.unlink(missing_ok=True)
        if error.errno in _WRITE_ERRNOS:
            raise write_error(out, error) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write(path: str | Path, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` through :func:`atomic_output`."""
    payload = data.encode("utf-8") if isinstance(data, str) else data
    with atomic_output(path) as tmp:
        # a FIFO or device is opened for writing only, never truncated by a rename
        with open(tmp, "wb") as f:
            f.write(payload)


@contextmanager
def atomic_directory_outputs(directory: Path) -> Iterator[Path]:
    """A private temporary directory inside ``directory`` for a writer that makes several
    files (the CSV writer: one per group and a ``.meta.json``); the caller moves each
    finished file out with :func:`move_into`. Whatever is left is removed."""
    try:
        tmp = Path(tempfile.mkdtemp(prefix=".ptinertia-", suffix=".part", dir=directory))
    except OSError as error:
        raise write_error(directory, error) from None
    try:
        yield tmp
    except OSError as error:
        if error.errno in _WRITE_ERRNOS:
            raise write_error(directory, error) from None
        raise
    except ValueError as error:
        # a writer's own one-line error names the file it was writing: name the target
        text = str(error).replace(f"{tmp}{os.sep}", f"{directory}{os.sep}")
        if text == str(error):
            raise
        try:
            renamed = type(error)(text)
        except Exception:  # an error type with another signature: keep it as it is
            raise error from None
        raise renamed from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def move_into(files: Iterable[Path], directory: Path) -> list[Path]:
    """Move each of ``files`` to ``directory`` under its own name (``os.replace``)."""
    moved = []
    mask = _umask()
    for f in files:
        dest = directory / f.name
        os.chmod(f, 0o666 & ~mask)
        os.replace(f, dest)
        moved.append(dest)
    return moved


def input_files(*paths: str | Path | None) -> list[Path]:
    """The files a run reads, given its input paths: each path, and for a CSV the files
    read with it (``BASE.GROUP.csv``, ``BASE.meta.json``), so none is written over."""
    out: list[Path] = []
    for p in paths:
        if p is None or str(p) == "":
            continue
        path = Path(p)
        out.append(path)
        if path.suffix.lower() == ".csv" and path.parent.is_dir():
            stem = path.name[: -len(path.suffix)]
            out.extend(
                q for q in path.parent.iterdir() if q.name.startswith(stem + ".") and q != path
            )
    return out
