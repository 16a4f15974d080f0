"""``.npz`` archives read and written one member at a time, every member's claims checked first.

:func:`read_npz` is what every reader of an ``.npz`` (motions, body models, checkpoints) uses
instead of ``np.load``: before an array is allocated, its ``.npy`` header is parsed and the
bytes its shape claims are compared with the bytes its member holds (a header claiming a
petabyte is refused in one line, not met with an allocation failure); a member that is not a
``.npy`` array, a name that comes twice, pickled objects (unless allowed), corrupt compressed
data and checksum mismatches are each refused with one line naming the file and the member.

:func:`write_npz` writes what ``np.savez`` writes, but takes the arrays as a dict, so that a key
may be any name (``file``, ``allow_pickle``: ``np.savez``'s own parameters) and is never taken
as an argument; a name that would put a path into the archive is refused (:func:`safe_key`).
"""

from __future__ import annotations

import ast
import math
import re
import zipfile
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from mdvae_cli.errors import InputError

#: deflate expands at most ~1032:1; a member claiming more than this is corrupt
_MAX_RATIO = 1100
#: longest .npy header read (numpy writes ~128 bytes)
_MAX_HEADER = 65536
#: characters that make a member name a path (or unprintable)
_UNSAFE = re.compile(r"[/\\:\x00-\x1f\x7f]")


def safe_key(key: str) -> bool:
    """Whether ``key`` can be an archive member name as it is: no folder separators, drive
    colons or control characters, not empty, ``.`` or ``..`` (unzipping ``../../x.npy`` would
    write outside the folder)."""
    return bool(key) and key not in (".", "..") and not _UNSAFE.search(key)


def safe_name(key: str, taken: set[str]) -> str:
    """A name for ``key`` that :func:`safe_key` accepts and is not in ``taken``: each run of
    unsafe characters becomes ``_``, leading and trailing dots and underscores go
    (``../../x`` -> ``x``, ``/abs/y`` -> ``abs_y``), and ``_2``, ``_3``... end a taken one."""
    base = _UNSAFE.sub("_", key)
    base = re.sub(r"_+", "_", base).strip("._") or "unnamed"
    name, n = base, 1
    while name in taken:
        n += 1
        name = f"{base}_{n}"
    return name


def read_npz(
    source: Path | str | BinaryIO,
    label: str | Path,
    allow_pickle: bool = False,
    pickle_option: str | None = None,
    max_total: int | None = None,
) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive, by key (member name less ``.npy``), in archive order.

    source: a path or a binary file object; label: how messages name it (the path, or
    ``body model NAME``). Pickled (object) arrays are refused unless ``allow_pickle``, which
    runs their code; ``pickle_option``: the option that allows them, named in the refusal.
    Raises InputError with one line for every defect, before allocating what a member only
    claims; ``max_total``: the bytes all its arrays may take together (None: no limit).
    """
    with NpzArchive(source, label, pickle_option, max_total=max_total) as npz:
        return {key: npz.read(key, allow_pickle) for key in npz.keys}


class NpzArchive:
    """An open ``.npz`` archive whose arrays are read one at a time, on demand (a body model
    file holds arrays nobody needs). ``keys``: member names less ``.npy``, in archive order.
    Use as a context manager, or call :meth:`close`. InputError when ``source`` is no zip
    archive, two members share a key, or its members unzip past ``max_total`` bytes."""

    def __init__(
        self,
        source: Path | str | BinaryIO,
        label: str | Path,
        pickle_option: str | None = None,
        max_member: int | None = None,
        max_total: int | None = None,
    ):
        self.label = str(label)
        self.pickle_option = pickle_option
        self.max_member = max_member  # bytes one array may take (None: what the file holds)
        self._own = None
        if isinstance(source, (str, Path)):
            if Path(source).is_file() and Path(source).stat().st_size == 0:
                raise InputError(f"{self.label}: empty file, not an .npz archive")
            source = self._own = Path(source).open("rb")
        try:
            self._zip = _open_zip(source, self.label)
        except BaseException:
            self.close()
            raise
        self._infos: dict[str, zipfile.ZipInfo] = {}
        for info in self._zip.infolist():
            key = info.filename.removesuffix(".npy")
            if key in self._infos:
                self.close()
                raise InputError(
                    f"{self.label}: holds two members named {info.filename!r}; which one is meant?"
                )
            self._infos[key] = info
        self.keys = list(self._infos)
        total = sum(i.file_size for i in self._infos.values())
        if max_total is not None and total > max_total:
            self.close()  # refused before any array is read: many members each under max_member
            raise InputError(
                f"{self.label}: its arrays add up to {_bytes(total)} unzipped, over the "
                f"{_bytes(max_total)} one file may take"
            )
        self.compressed = any(i.compress_type != zipfile.ZIP_STORED for i in self._infos.values())

    def read(
        self,
        key: str,
        allow_pickle: bool = False,
        plain_data: bool = False,
        unpickle: Callable[[BinaryIO, str], Any] | None = None,
    ) -> np.ndarray:
        """The array ``key``, its header's claims checked before it is allocated.
        ``plain_data``: an object array is read through the data unpickler
        (``formats.safe_data``: numbers, strings, arrays and plain containers, nothing run)
        and refused only when it holds anything else (unless ``allow_pickle``). ``unpickle``:
        an object array is read by ``unpickle(stream, label)`` instead (a restricted unpickler,
        e.g. a body model's, which rebuilds scipy.sparse matrices)."""
        info = self._infos[key]
        if not info.filename.endswith(".npy"):
            raise InputError(
                f"{self.label}: member {info.filename!r} is not a numpy array (.npy); an .npz "
                "holds only arrays"
            )
        if info.flag_bits & 0x1:
            raise InputError(
                f"{self.label}: member {info.filename!r} is encrypted (password-protected); "
                "save the arrays without a password"
            )
        where = f"{self.label}: {key!r}"
        if self.max_member is not None and info.file_size > self.max_member:
            size, most = _bytes(info.file_size), _bytes(self.max_member)
            raise InputError(f"{where} is {size}, over the {most} one array of it may take")
        return _read_member(self._zip, info, key, self.label, allow_pickle, self.pickle_option,
                            plain_data, unpickle)  # fmt: skip

    def __getitem__(self, key: str) -> np.ndarray:
        return self.read(key)

    def close(self) -> None:
        if getattr(self, "_zip", None) is not None:
            self._zip.close()
        if self._own is not None:
            self._own.close()

    def __enter__(self) -> NpzArchive:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _open_zip(fh: BinaryIO, label: str) -> zipfile.ZipFile:
    start = fh.tell()
    head = fh.read(4)
    fh.seek(start)
    if not head:
        raise InputError(f"{label}: empty file, not an .npz archive")
    try:
        return zipfile.ZipFile(fh)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError):
        if head == b"PK\x03\x04":  # a zip that lost its end (a copy cut short)
            raise InputError(f"{label}: truncated or corrupt .npz archive") from None
        raise InputError(f"{label}: not an .npz archive") from None


def _read_member(
    archive: zipfile.ZipFile,
    info: zipfile.ZipInfo,
    key: str,
    label: str,
    allow_pickle: bool,
    pickle_option: str | None,
    plain_data: bool = False,
    unpickle: Callable[[BinaryIO, str], Any] | None = None,
) -> np.ndarray:
    where = f"{label}: {key!r}"
    try:
        with archive.open(info) as fh:
            shape, dtype, header_bytes = _header(fh, where)
            if dtype.hasobject:
                if unpickle is not None:
                    return unpickle(fh, where)
                if not allow_pickle:
                    hint = (f"re-run with {pickle_option} only if you trust the file (it runs "
                            "their code)" if pickle_option else
                            "they are never loaded (they could run code): save it as plain "
                            "arrays")  # fmt: skip
                    if plain_data:
                        return _plain_objects(fh, where, hint)
                    raise InputError(f"{where} holds pickled Python objects; {hint}")
            else:
                _check_size(info, shape, dtype, header_bytes, where)
            fh.seek(0)
            return np.lib.format.read_array(
                fh, allow_pickle=allow_pickle, max_header_size=_MAX_HEADER
            )
    except InputError:
        raise
    except zipfile.BadZipFile as exc:
        why = "checksum mismatch" if "CRC" in str(exc) else "its zip entry is damaged"
        raise InputError(f"{where} is corrupt ({why})") from None
    except zlib.error:
        raise InputError(f"{where} is corrupt (its compressed data cannot be read)") from None
    except MemoryError:
        raise InputError(f"{where} does not fit in memory") from None
    except RuntimeError as exc:  # zipfile: encrypted, or a compression it cannot read
        raise InputError(f"{where} cannot be read ({exc})") from None
    except (ValueError, EOFError, OSError, NotImplementedError):
        raise InputError(f"{where} is not a readable .npy array (truncated or damaged)") from None
    except Exception as exc:  # an allowed pickle that fails to load
        if allow_pickle:
            raise InputError(f"{where}: its pickled objects cannot be loaded ({exc})") from None
        raise


def _plain_objects(fh: BinaryIO, where: str, hint: str) -> np.ndarray:
    """The object array whose pickle starts at ``fh`` (after its ``.npy`` header), built by
    the data unpickler: plain data only (an AMASS SMPL-X file's ``markers_latent_vids``, a
    dict of marker names to vertex ids), nothing run. InputError when it asks for more."""
    from mdvae_cli.formats.safe_data import unpickle

    try:
        value = unpickle(fh, where)
    except InputError:
        what = "numbers, strings, arrays, lists and dicts"
        raise InputError(
            f"{where} holds pickled Python objects that are not plain data ({what}); {hint}"
        ) from None
    if not isinstance(value, np.ndarray):
        raise InputError(f"{where} is not a readable .npy array (its pickle holds no array)")
    return value


def _header(fh: BinaryIO, where: str) -> tuple[tuple[int, ...], np.dtype, int]:
    """Shape, dtype and header length of a ``.npy`` stream, read without numpy's reader (so
    that nothing is allocated yet)."""
    bad = InputError(f"{where} is not a readable .npy array (bad header)")
    magic = fh.read(8)
    if len(magic) < 8 or magic[:6] != b"\x93NUMPY" or magic[6] not in (1, 2, 3):
        raise bad
    width = 2 if magic[6] == 1 else 4
    size = int.from_bytes(fh.read(width), "little")
    if size > _MAX_HEADER:
        raise bad
    raw = fh.read(size)
    try:
        header = ast.literal_eval(raw.decode("utf-8" if magic[6] == 3 else "latin1"))
        shape, fortran = header["shape"], header["fortran_order"]
        dtype = np.lib.format.descr_to_dtype(header["descr"])
    except (ValueError, SyntaxError, TypeError, KeyError, MemoryError, RecursionError):
        raise bad from None
    valid_shape = isinstance(shape, tuple) and all(
        isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape
    )
    if len(raw) < size or not valid_shape or not isinstance(fortran, bool):
        raise bad
    return shape, dtype, 8 + width + size


def _check_size(
    info: zipfile.ZipInfo, shape: tuple[int, ...], dtype: np.dtype, header: int, where: str
) -> None:
    """InputError when the member cannot hold what its header claims (or claims to expand
    further than deflate can)."""
    need = math.prod(shape) * dtype.itemsize
    have = info.file_size - header
    stored = info.compress_type == zipfile.ZIP_STORED
    if (stored and info.compress_size < info.file_size) or (
        info.file_size > _MAX_RATIO * info.compress_size + 1024
    ):
        raise InputError(f"{where} is corrupt (its zip entry claims {info.file_size:,} bytes)")
    if need > have:
        raise InputError(
            f"{where} claims shape {shape} ({_bytes(need)}) but holds only {max(have, 0):,} "
            "bytes: the file is truncated or corrupt"
        )


def _bytes(n: int) -> str:
    for unit in ("bytes", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:,} {unit}" if unit == "bytes" else f"{n:.3g} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


def write_npz(fh: BinaryIO, arrays: Mapping[str, np.ndarray], compress: bool = False) -> None:
    """Write ``arrays`` to the open binary file ``fh`` as ``np.savez`` (``compress``:
    ``np.savez_compressed``) would, each key as ``<key>.npy``; any key name :func:`safe_key`
    accepts, including ``file`` and ``allow_pickle``. InputError for any other."""
    for key in arrays:
        if not safe_key(key):
            raise InputError(f"cannot write the array {key!r}: its name is a path")
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(fh, "w", compression=method, allowZip64=True) as zf:
        for key, value in arrays.items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=True)
