"""Output files: checked before a run starts, written whole or not at all.

Every command names its inputs and outputs up front; :func:`check_outputs` refuses, before any
work is done, an output that resolves to an input file (it would destroy it), a folder, a
folder that cannot be created, or a suffix the writer does not produce. :func:`atomic` then
writes each output to a temporary file in the same folder and renames it over the target
(``os.replace``, atomic on POSIX and Windows), so a crash leaves the old file whole.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from ebus_env.errors import ConfigError

TABLE_SUFFIXES = (".parquet", ".csv")
JSON_SUFFIXES = (".json",)
PLOT_SUFFIXES = (".png", ".svg", ".pdf")
HTML_SUFFIXES = (".html", ".htm")
YAML_SUFFIXES = (".yaml", ".yml")


def same_file(a: Path, b: Path) -> bool:
    """True when ``a`` and ``b`` name one file (symlinks, ``..`` and hard links included)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def same_bytes(a: Path, b: Path) -> bool:
    """True when files ``a`` and ``b`` hold the same bytes (a copy under another name)."""
    a, b = Path(a), Path(b)
    if a.stat().st_size != b.stat().st_size:
        return False
    return hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()


def check_output(path: Path, option: str, suffixes: Iterable[str],
                 inputs: Iterable[Path] = ()) -> Path:
    """Check one output path before the run; create its folder. Returns the path.

    Parameters
    ----------
    path
        The output file as given.
    option
        The option that named it (``--out``), for the message.
    suffixes
        Accepted suffixes (lower case, with the dot).
    inputs
        Files the command reads; the output may not be any of them.
    """
    path = Path(path)
    suffixes = tuple(suffixes)
    for source in inputs:
        if source is not None and Path(source).exists() and same_file(path, Path(source)):
            raise ConfigError(f"{option} {path} is an input of this command and would be "
                              "overwritten. Fix: write to another file name.")
    if path.is_dir():
        raise ConfigError(f"{option} {path} is a folder. Fix: give a file name, e.g. "
                          f"{path / ('out' + suffixes[0])}.")
    if path.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: suffix '{path.suffix}' is not one this output is "
                          f"written as. Accepted: {', '.join(suffixes)}. Fix: rename the file.")
    check_folder(path.parent, option)
    return path


def check_outputs(outputs: Iterable[tuple[Path | None, str, Iterable[str]]],
                  inputs: Iterable[Path]) -> None:
    """Check each ``(path, option, suffixes)`` output given (None: not asked for) with
    :func:`check_output` against the ``inputs``."""
    inputs = list(inputs)
    for path, option, suffixes in outputs:
        if path is not None:
            check_output(path, option, suffixes, inputs)


def output_folder(out: Path, option: str) -> Path:
    """``out`` as a folder to write into later, refused before the run when it is a file (and
    not made yet: a run that fails first leaves nothing behind)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{option} {out}: is a file; give a folder (new or existing).")
    return out


def refuse_overwriting(folder: Path, option: str, names: Iterable[str], inputs) -> None:
    """Refuse, before the run, an output ``folder / name`` that is one of the ``inputs``
    (paths, or None): writing it would destroy the input."""
    for source in inputs:
        if source is None or not Path(source).is_file():
            continue
        for name in names:
            if same_file(Path(folder) / name, Path(source)):
                raise ConfigError(f"{option} {folder}: the command writes {name} there, which "
                                  f"is its input {source}. Fix: give another {option}, or "
                                  "move the input elsewhere.")


def check_folder(folder: Path, option: str, inputs: Iterable[Path] = ()) -> Path:
    """Create ``folder`` (and parents) if needed; refuse a file or an unwritable place, and a
    folder that holds an input (an output folder is written into freely)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"{option} {folder} is a file, not a folder. Fix: name a folder.")
    for source in inputs:
        if Path(source).resolve().parent == folder.resolve():
            raise ConfigError(f"{option} {folder} holds the input {source}; outputs written "
                              "there could overwrite it. Fix: name another folder.")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{option}: cannot create the folder {folder} ({exc.strerror}). "
                          "Fix: name a folder you can write to.") from None
    if not os.access(folder, os.W_OK):
        raise ConfigError(f"{option}: the folder {folder} is not writable. Fix: name a folder "
                          "you can write to.")
    return folder


@contextlib.contextmanager
def atomic(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers infer the format);
    rename it over ``path`` when the block ends without an error, delete it otherwise."""
    path = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open() would
        os.chmod(tmp, path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_with(path: str | Path, writer: Callable[[Path], object]) -> Path:
    """Call ``writer(tmp)`` on a temporary file beside ``path``, then rename it to ``path``."""
    with atomic(path) as tmp:
        writer(tmp)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file; return the path."""
    with atomic(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def _clean(value):
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):
        return _clean(value.item())
    return value


def write_json(data: dict, path: str | Path) -> None:
    """JSON with NaN/inf written as null."""
    write_text(path, json.dumps(_clean(data), indent=2) + "\n")
