"""Small file helpers shared by every writer: nothing is ever written half-way.

* :func:`atomic_write_text` / :func:`atomic_write_bytes` write through a temporary file
  in the target's folder and a rename, so a reader never sees a partial file and a
  failure leaves any old file intact.  The file gets the permissions a plain
  ``open(path, "w")`` would give: ``0o666 & ~umask`` for a new file (``-rw-r--r--``
  under the usual umask 022), the old file's mode when it replaces one.
* :func:`check_outputs` refuses an output that is also an input (``-o`` equal to
  ``--data``) or a folder, before any work is done.

An output that cannot be written (no permission, a folder in the way, a full disk) is
one :class:`~kincal.errors.KincalError` line naming the path; so is an input that cannot
be read as text (:func:`read_text`).
"""

from __future__ import annotations

import json
import os
import stat
import sys
import tempfile
import threading
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.errors import KincalError

_UMASK_LOCK = threading.Lock()


def read_text(path: str | os.PathLike[str], what: str = "file",
              error: type[KincalError] = KincalError) -> str:
    """The UTF-8 text of an input file (a byte-order mark dropped).

    Every failure is one ``error`` line naming the file: ``no such {what}``, ``is a
    folder, not a {what}``, ``not a UTF-8 text file (byte N)``, ``cannot read: ...``.
    """
    src = str(path)
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise error(f"no such {what}", source=src) from None
    except IsADirectoryError:
        raise error(f"is a folder, not a {what}", source=src) from None
    except UnicodeDecodeError as exc:
        raise error(f"not a UTF-8 text file (byte {exc.start})", source=src) from None
    except OSError as exc:
        raise error(f"cannot read: {exc.strerror or exc}", source=src) from None


def current_umask() -> int:
    """The process's umask (read by setting and restoring it, under a lock)."""
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _mode_for(target: Path) -> int:
    """Permissions for ``target``: those of the file it replaces, else ``0o666 & ~umask``."""
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~current_umask()


def _cannot_write(path: str | os.PathLike[str], exc: OSError) -> KincalError:
    reason = exc.strerror or exc.__class__.__name__
    if isinstance(exc, IsADirectoryError) or Path(path).is_dir():
        reason = "it is a folder"
    return KincalError(f"cannot write: {reason}", source=str(path))


def _atomic_write(path: str | os.PathLike[str], data: bytes) -> None:
    target = Path(path)
    if target.is_dir():
        raise KincalError("cannot write: it is a folder", source=str(path))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    except OSError as exc:
        raise _cannot_write(path, exc) from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, _mode_for(target))
        os.replace(tmp, target)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise _cannot_write(path, exc) from None
        raise


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; ``path == "-"`` writes to stdout.

    Through a temporary file in the same folder, then a rename: a reader never sees a
    partial file, and a failure leaves any old file intact.  Permissions follow the
    umask (a replaced file keeps its mode).
    """
    if str(path) == "-":
        sys.stdout.write(text)
        if not text.endswith("\n"):
            sys.stdout.write("\n")
        sys.stdout.flush()
        return
    _atomic_write(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Binary twin of :func:`atomic_write_text` (no stdout)."""
    _atomic_write(path, data)


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def check_outputs(outputs: Mapping[str, str | os.PathLike[str] | None],
                  inputs: Mapping[str, Iterable[str | os.PathLike[str]] | str | None]
                  ) -> None:
    """Refuse, before any work, outputs that would clobber an input or cannot be files.

    Args:
        outputs: ``{option: path}`` of the files a command will write (``None`` and
            ``"-"`` are skipped), e.g. ``{"-o": "cal.yaml", "--json": "-"}``.
        inputs: ``{option: path or paths}`` it reads, e.g. ``{"--data": ["a.csv"]}``.

    Raises one :class:`~kincal.errors.KincalError` line: ``option -o: 'a.csv' is also
    the input of --data; choose another name`` (also for two outputs on one path, and
    an output that is an existing folder).
    """
    ins: list[tuple[str, Path]] = []
    for opt, paths in inputs.items():
        if paths is None:
            continue
        for given in [paths] if isinstance(paths, str | os.PathLike) else paths:
            if given is not None and str(given) != "-":
                ins.append((opt, Path(given)))
    seen: list[tuple[str, Path]] = []
    for opt, p in outputs.items():
        if p is None or str(p) == "-":
            continue
        path = Path(p)
        if path.is_dir():
            raise KincalError(f"option {opt}: {str(p)!r} is a folder; give a file name")
        for iopt, ip in ins:
            if _same_file(path, ip):
                raise KincalError(f"option {opt}: {str(p)!r} is also the input of {iopt}; "
                                  "writing it would destroy the input: choose another name")
        for oopt, op in seen:
            if _same_file(path, op):
                raise KincalError(f"options {oopt} and {opt} name the same file {str(p)!r}")
        seen.append((opt, path))


def _jsonable(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def json_text(data: Any) -> str:
    """``data`` (NumPy arrays allowed) as indented JSON text; non-finite floats as null."""
    return json.dumps(_finite(data), indent=2, default=_jsonable, allow_nan=False) + "\n"


def _finite(obj: Any) -> Any:
    """NaN / inf -> None, so that the JSON is standard (``NaN`` is not JSON)."""
    import math

    import numpy as np

    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.ndarray) and obj.dtype.kind == "f":
        return [_finite(v) for v in obj.tolist()]
    if isinstance(obj, np.floating):
        return _finite(float(obj))
    if isinstance(obj, Mapping):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def write_json(path: str | os.PathLike[str], data: Any) -> None:
    """Write ``data`` (NumPy arrays allowed) as indented JSON, atomically; ``-`` is stdout."""
    atomic_write_text(path, json_text(data))


def html_table(header: Sequence[str], rows: Sequence[Sequence[object]],
               caption: str = "") -> str:
    """A small HTML table (every cell escaped) for notebook displays (``_repr_html_``);
    without rows, only the caption (an empty table with headers says nothing)."""
    import html as _html

    if not rows:
        return f"<p>{_html.escape(caption)}</p>"

    head = "".join(f"<th>{_html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{_html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    cap = f"<caption style='text-align:left'>{_html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
