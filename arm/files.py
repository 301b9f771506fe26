"""Files in and out: the one place where sixaxis-track opens what a user names.

**Outputs.** Every file the project writes goes through :func:`atomic_path` (or
:func:`atomic_write_text`, :func:`atomic_write_bytes` over it): the content goes to a temporary
beside the file and is renamed onto it when whole, so a reader sees the old or the whole new file.
What already stands at the path decides what happens:

=====================================  ========================================================
at the path                            written
=====================================  ========================================================
nothing, or a regular file             atomically, as above
a symbolic link to a regular file      atomically, onto the file it points to (the link stays)
``-``                                  to standard output, in place (text outputs only)
a directory, a device (``/dev/null``,  refused (:class:`OutputError`): a rename would replace it
``/dev/full``), a FIFO, a socket, or   with a regular file, which as root destroys ``/dev/null``
a link to one of them                  and ``/dev/stdout``; say ``-`` for standard output
=====================================  ========================================================

:func:`check_output` says the same before any work, and also refuses a file name or a path longer
than the file system allows, an output that is one of the inputs, and a folder where no file can
be made. Missing folders of an output's path are made (:func:`make_folders`, which says so in
the log), by every writer alike.

**Inputs.** :func:`read_input_text` and :func:`read_input_bytes` read only a regular file (a FIFO
would block for ever, ``/dev/zero`` never ends), opened without blocking and checked on the open
descriptor, and only up to a stated size (:data:`MAX_INPUT_BYTES`, by kind of file), so a wrong
file is one line naming it, never a hang or a ``MemoryError``.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import stat
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from importlib.resources.abc import Traversable
from pathlib import Path

from arm.errors import InputFileError, OutputError

__all__ = [
    "MAX_INPUT_BYTES",
    "STDOUT",
    "InputFileError",
    "OutputError",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_input_file",
    "check_output",
    "folder_problem",
    "input_problem",
    "is_dir",
    "is_file",
    "is_stdout",
    "make_folders",
    "output_problem",
    "read_input_bytes",
    "read_input_text",
    "remove_stale_temporaries",
    "shown",
]

STDOUT = "-"  # an output path that means standard output

log = logging.getLogger(__name__)

#: The largest input of each kind that is read, bytes (docs/format.md, limits): a measurement CSV
#: of 1 GiB holds about three million rows (the 480,000 rows of one large campaign take 150 MB).
MAX_INPUT_BYTES: dict[str, int] = {
    "csv": 1 << 30,
    "toml": 16 << 20,
    "urdf": 64 << 20,
    "json": 64 << 20,
    "python": 16 << 20,
    "weights": 256 << 20,
}


# -- what stands at a path --------------------------------------------------------------------------
def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _special(path: Path) -> str | None:
    """What non-regular thing stands at ``path`` (following links), as a phrase naming the link's
    target where there is one; None for nothing there or a regular file."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    if stat.S_ISREG(st.st_mode):
        return None
    what = _kind(st.st_mode)
    if os.path.islink(path):
        return f"a symbolic link to {what} ({os.path.realpath(path)})"
    return what


def is_file(path: str | Path | Traversable) -> bool:
    """Whether a regular file stands at ``path`` (links followed). Every path a user gives is
    asked this way: a path the OS refuses to look at (a name over 255 bytes, a NUL byte, a loop
    of links, a folder it may not enter) is no file, where ``Path.is_file`` raises for some."""
    try:
        return path.is_file() if not isinstance(path, str | Path) else os.path.isfile(path)
    except (OSError, ValueError):
        return False


def is_dir(path: str | Path) -> bool:
    """Whether a folder stands at ``path`` (links followed); False for a path the OS refuses to
    look at, as :func:`is_file`."""
    try:
        return os.path.isdir(path)
    except (OSError, ValueError):
        return False


def is_stdout(path: str | Path | None) -> bool:
    """Whether ``path`` is ``-``: standard output."""
    return path is not None and str(path) == STDOUT


def shown(path: str | Path, width: int = 120) -> str:
    """``path`` as a message shows it: whole, or its start and end around ``...`` when longer than
    ``width`` characters (an over-long path must not fill the screen)."""
    text = str(path)
    if len(text) <= width:
        return text
    return f"{text[: width // 2]}...{text[-(width // 2 - 3) :]}"


def _name_max(folder: Path) -> tuple[int, int]:
    """The longest file name and path the file system takes (255 and 4096 where it cannot say)."""
    while not os.path.exists(folder) and folder != folder.parent:
        folder = folder.parent
    try:
        return os.pathconf(folder, "PC_NAME_MAX"), os.pathconf(folder, "PC_PATH_MAX")
    except (OSError, ValueError):
        return 255, 4096


def _length_problem(path: Path) -> str | None:
    """Why ``path`` cannot name a file at all (a NUL byte, a name or path beyond the file
    system's limits), or None."""
    if "\0" in str(path):
        return "a path with a NUL byte, which no file system takes"
    full = path.absolute()
    name_max, path_max = _name_max(full.parent)
    for part in full.parts:
        if len(os.fsencode(part)) > name_max:
            return (
                f"a file or folder name of {len(os.fsencode(part))} bytes; the file system "
                f"takes at most {name_max}"
            )
    if len(os.fsencode(str(full))) >= path_max:
        return f"a path of {len(os.fsencode(str(full)))} bytes; the system takes at most {path_max - 1}"
    return None


def folder_problem(folder: str | Path) -> str | None:
    """Why no file can be created in ``folder``, or in the nearest folder above it that exists
    (where it would be made): ``"... is not a directory"``, ``"cannot write in ... (reason)"``;
    None when a probe file can be made there (it is removed at once)."""
    why = _length_problem(Path(folder))
    if why:
        return why
    parent = Path(folder).absolute()
    while not os.path.exists(parent) and parent != parent.parent:
        parent = parent.parent
    if not os.path.isdir(parent):
        return f"{parent} is not a directory"
    try:
        fd, probe = tempfile.mkstemp(dir=parent, prefix=".sixaxis-probe.", suffix=".tmp")
    except OSError as exc:
        return f"cannot write in {parent} ({exc.strerror or exc})"
    os.close(fd)
    os.unlink(probe)
    return None


def output_problem(path: str | Path, stdout_ok: bool = True) -> str | None:
    """Why ``path`` cannot be written as an output file (see the module's table), or None."""
    if is_stdout(path):
        return None if stdout_ok else "this output cannot go to standard output; give a file"
    path = Path(path)
    why = _length_problem(path)
    if why:
        return why
    special = _special(path)
    if special is not None:
        if special == "a directory":
            return "is a directory; give the file to write"
        instead = "give a file, or - for standard output" if stdout_ok else "give a file"
        return f"is {special}, not a regular file; writing would replace it ({instead})"
    return folder_problem(_target(path).parent)


def _target(path: Path) -> Path:
    """The file a write of ``path`` replaces: the file a link points to, else ``path``."""
    return Path(os.path.realpath(path)) if os.path.islink(path) else path


def _same_file(a: Path, b: Path) -> bool:
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except (OSError, ValueError):  # a path the OS refuses to look at is no input
        return False


def check_output(
    path: str | Path,
    inputs: Sequence[str | Path | None] = (),
    option: str = "--output",
    stdout_ok: bool = True,
) -> None:
    """Refuse, before any work, an output that would replace one of ``inputs`` (the same file by
    path or by link) or that cannot be written (:func:`output_problem`); ``-`` (standard output)
    where ``stdout_ok``. Raises :class:`OutputError` naming ``option`` and the path."""
    if not is_stdout(path):
        for inp in inputs:
            if inp is not None and _same_file(Path(path), Path(inp)):
                raise OutputError(
                    f"{option} {path}: is the input {inp}; writing it would replace that file "
                    "(choose another output path)"
                )
    why = output_problem(path, stdout_ok)
    if why:
        raise OutputError(f"{option} {shown(path)}: {why}")


# -- writing ----------------------------------------------------------------------------------------
def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


STALE_LEGACY_SECONDS = 3600.0  # a temporary without a writer's pid, older than this, is stale
_TEMP_NAME = 180  # bytes of the file's name kept in its temporary's (names go up to 255)


def _temp_prefix(name: str) -> str:
    stem = name
    while len(os.fsencode(stem)) > _TEMP_NAME:
        stem = stem[:-1]
    return f".{stem}."


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # another user's process, or we cannot tell: leave its file alone
    return True


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove the temporaries that :func:`atomic_path` left beside ``path`` when its process was
    killed (SIGKILL runs no cleanup): ``.NAME.PID.XXXX.tmp`` whose writer PID no longer runs, and
    those of older versions without a PID once an hour old. A live writer's file is kept.
    Returns the paths removed."""
    path = Path(path)
    prefix = _temp_prefix(path.name)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        name = entry.name
        if not (name.startswith(prefix) and name.endswith(".tmp")):
            continue
        middle = name[len(prefix) : -len(".tmp")]
        pid_text, _, rest = middle.partition(".")
        try:
            if rest and pid_text.isdigit():
                pid = int(pid_text)
                if pid == os.getpid() or _pid_alive(pid):
                    continue
            elif now - entry.stat(follow_symlinks=False).st_mtime < STALE_LEGACY_SECONDS:
                continue
            os.unlink(entry.path)
            removed.append(Path(entry.path))
        except OSError:
            continue
    return removed


def make_folders(folder: str | Path) -> None:
    """Make ``folder`` and every missing folder above it, saying so: one INFO record of this
    module's logger naming the folder (the ``sixaxis`` commands print it), none where it exists.
    Every writer makes the folders its output needs this way (an output's missing folders are
    made, never refused), so that a mistyped folder is seen at once, not found later empty."""
    folder = Path(folder)
    if is_dir(folder):
        return
    folder.mkdir(parents=True, exist_ok=True)
    log.info("created the folder %s (it did not exist)", shown(folder))


def _cannot(path: Path, exc: OSError) -> OutputError:
    return OutputError(f"{path}: cannot write ({exc.strerror or exc})")


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block ends
    without error, removed otherwise. Readers see the old or the whole new file, never a part,
    and the file gets the permissions of a plain ``open`` (the umask's), not mkstemp's 0600.

    ``path`` may be absent, a regular file, or a link to one (the file it points to is replaced,
    the link kept); anything else (a directory, a device, a FIFO, ``-``) is refused with
    :class:`OutputError`, never replaced.

    The temporary is ``.NAME.PID.XXXX.tmp``: a process killed while writing leaves it, and the
    next write of the same file removes it (:func:`remove_stale_temporaries`)."""
    given = Path(path)
    if is_stdout(path):
        raise OutputError(f"{given}: this output cannot go to standard output; give a file")
    why = _length_problem(given) or (None if _special(given) is None else output_problem(given))
    if why:
        raise OutputError(f"{shown(given)}: {why}")
    target = _target(given)
    try:
        make_folders(target.parent)
        remove_stale_temporaries(target)
        fd, tmp = tempfile.mkstemp(
            dir=target.parent, prefix=f"{_temp_prefix(target.name)}{os.getpid()}.", suffix=".tmp"
        )
        os.close(fd)
    except OSError as exc:
        raise _cannot(given, exc) from None
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _stdout_write(data: str | bytes) -> None:
    if isinstance(data, bytes):
        sys.stdout.flush()
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
    else:
        sys.stdout.write(data)
        sys.stdout.flush()


def _write(path: str | Path, data: str | bytes) -> None:
    if is_stdout(path):
        _stdout_write(data)
        return
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            raw = data if isinstance(data, bytes) else data.encode("utf-8")
            with open(tmp, "wb") as fh:
                fh.write(raw)
                fh.flush()
                os.fsync(fh.fileno())
    except OSError as exc:  # a full disk, a read-only file system
        raise _cannot(path, exc) from None


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) so that readers see either the old or the whole new content, never
    a part; ``-`` writes it to standard output."""
    _write(path, text)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """:func:`atomic_write_text` for bytes."""
    _write(path, data)


# -- reading ----------------------------------------------------------------------------------------
def input_problem(path: str | Path, what: str = "file") -> str | None:
    """Why ``path`` cannot be read as an input ``what`` (not found, not a regular file), or None.
    Only looks: nothing is opened."""
    path = Path(path)
    if "\0" in str(path):
        return "cannot be read: a path with a NUL byte"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return f"{what} not found"
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return f"cannot be read: {_length_problem(path) or exc.strerror}"
        return f"cannot be read ({exc.strerror or exc})"
    if not stat.S_ISREG(st.st_mode):
        return (
            f"is {_special(path) or _kind(st.st_mode)}, not a regular file; give the {what} itself"
        )
    return None


def check_input_file(
    path: str | Path,
    what: str = "file",
    kind: str = "csv",
    error: type[Exception] = InputFileError,
) -> Path:
    """``path`` if it is a regular file no larger than ``MAX_INPUT_BYTES[kind]``, else ``error``
    naming it (for readers that open the file themselves: an import, ``numpy.load``)."""
    path = _regular_file(path, what, error)
    size = os.stat(path).st_size
    if size > MAX_INPUT_BYTES[kind]:
        raise error(_too_large(path, size, what, MAX_INPUT_BYTES[kind]))
    return path


def _regular_file(path: str | Path, what: str, error: type[Exception]) -> Path:
    """``path`` as a Path if :func:`input_problem` finds nothing wrong, else ``error`` saying
    what is."""
    path = Path(path)
    why = input_problem(path, what)
    if why:
        raise error(f"{shown(path)}: {why}")
    return path


def _too_large(path: Path, size: int, what: str, limit: int) -> str:
    return f"{path}: {_size_text(size)}; {what}s are read up to {_size_text(limit)}"


def _size_text(n: int) -> str:
    for unit, f in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= f:
            return f"{n / f:.3g} {unit}"
    return f"{n} bytes"


def read_input_bytes(
    path: str | Path,
    what: str = "file",
    kind: str = "csv",
    error: type[Exception] = InputFileError,
) -> bytes:
    """The bytes of the regular file ``path``, at most ``MAX_INPUT_BYTES[kind]``. Anything else
    (missing, a directory, a FIFO, a device, too large, unreadable) is ``error`` naming the file:
    the file is opened without blocking and checked on its descriptor before a byte is read."""
    path = _regular_file(path, what, error)
    limit = MAX_INPUT_BYTES[kind]
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced since it was looked at
            raise error(f"{path}: is {_kind(st.st_mode)}, not a regular file")
        if st.st_size > limit:
            raise error(_too_large(path, st.st_size, what, limit))
        try:
            # as much as the file holds (a read of the limit would allocate the limit), then on
            # in chunks while it grows, up to one byte past the limit
            chunks = [fh.read(st.st_size + 1)]
            size = len(chunks[0])
            while size > st.st_size and size <= limit:
                more = fh.read(min(1 << 20, limit + 1 - size))
                if not more:
                    break
                chunks.append(more)
                size += len(more)
            data = b"".join(chunks)
        except OSError as exc:
            raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise error(f"{path}: larger than {_size_text(limit)}, the limit for {what}s")
    return data


def read_input_text(
    path: str | Path,
    what: str = "file",
    kind: str = "csv",
    error: type[Exception] = InputFileError,
) -> str:
    """The UTF-8 text of the regular file ``path`` (a byte-order mark allowed), as
    :func:`read_input_bytes` reads it; a byte that is not UTF-8 is named by its line and column."""
    data = read_input_bytes(path, what, kind, error)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        start = exc.start
        line = data.count(b"\n", 0, start) + 1
        column = start - (data.rfind(b"\n", 0, start) + 1) + 1
        raise error(
            f"{path}, line {line}, column {column}: not a UTF-8 text file (byte "
            f"0x{data[start]:02x}: a Latin-1 or Windows file? save it as UTF-8)"
        ) from None
