"""The run log: writing and reading `log.npz` bit-identically, and writing it as it grows.

numpy's savez stamps the current time into the zip entries, so two identical runs would give
different files; `save_npz` writes the same arrays as a zip with a fixed timestamp and sorted
keys, so the same seed gives the same bytes. Floating-point arrays (measurements, states: noise
in every bit of the mantissa) are stored as they are: deflate took a fifth of their size for
about a tenth of a run's CPU (a 10-s coop-denied flight: 8.8 MB of floats deflated to 6.5 MB in
0.23 s); every other array (strings, integers, flags: runs of equal bytes) is deflated. Either
way numpy.load reads it.

`LogWriter` collects a log whose arrays arrive in pieces of rows (the simulation appends a chunk
of ticks at a time, the sensors a sample at a time). With a spill directory, a key's rows are
held in memory only up to `spill_bytes`, then written to a .npy chunk file there, so a long run
of a large swarm keeps a bounded part of its log in memory; `save` streams every key's chunks
into the same log.npz bytes that `save_npz` writes for the concatenated arrays (deflate output
does not depend on how its input is split). `NpzLog` reads a saved log back key by key.
"""
from __future__ import annotations

import io
import shutil
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from testbed.errors import RunError

_EPOCH = (1980, 1, 1, 0, 0, 0)
SPILL_BYTES = 4 * 2**20  # rows of one key held in memory before they go to a chunk file


def _member(zf: zipfile.ZipFile, key: str, size: int, pieces: Iterator[bytes], dtype: np.dtype) -> None:
    """Write `key`.npy (size bytes, given piece by piece) with the fixed timestamp, stored if the
    array is floating point (or complex), deflated otherwise (module docstring)."""
    info = zipfile.ZipInfo(key + ".npy", date_time=_EPOCH)
    info.compress_type = zipfile.ZIP_STORED if dtype.kind in "fc" else zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    info.file_size = size  # as ZipFile.writestr sets it: decides zip64 before the first byte
    with zf.open(info, "w") as dest:
        for piece in pieces:
            dest.write(piece)


def _whole(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays to a .npz file (loadable with numpy.load) deterministically."""
    log = LogWriter()
    for key, array in arrays.items():
        log.put(key, array)
    log.save(path)


class LogWriter:
    """A run log built from whole arrays (`put`) and arrays appended a piece of rows at a time
    (`append`: pieces (R_i, ...) of one key share their trailing shape; the dtype is that of
    their concatenation, e.g. the widest unicode width).

    spill_dir: where pieces go once a key holds more than spill_bytes (None: SPILL_BYTES) in
    memory (spill_dir None: all in memory). `arrays()` gives the whole log as a dict,
    `save(path)` writes log.npz, `close()` deletes the spill directory.
    """

    def __init__(self, spill_dir: Path | None = None, spill_bytes: int | None = None):
        self.spill_dir, self.spill_bytes = spill_dir, SPILL_BYTES if spill_bytes is None else spill_bytes
        self._whole: dict[str, np.ndarray] = {}
        self._pieces: dict[str, list[np.ndarray | Path]] = {}  # in order; Paths are spilled chunks
        self._held: dict[str, int] = {}  # bytes of a key's in-memory pieces
        self._dtype: dict[str, np.dtype] = {}
        self._shape: dict[str, tuple[int, ...]] = {}  # trailing shape
        self._rows: dict[str, int] = {}
        self._files = 0

    def __contains__(self, key: str) -> bool:
        return key in self._whole or key in self._pieces

    def put(self, key: str, array: np.ndarray) -> None:
        if key in self:
            raise ValueError(f"log key {key!r} written twice")
        self._whole[key] = np.asarray(array)

    def append(self, key: str, rows: np.ndarray) -> None:
        rows = np.asarray(rows)
        if key in self._whole:
            raise ValueError(f"log key {key!r} is a whole array, rows cannot be appended")
        if key not in self._pieces:
            self._pieces[key], self._held[key], self._rows[key] = [], 0, 0
            self._dtype[key], self._shape[key] = rows.dtype, rows.shape[1:]
        elif rows.shape[1:] != self._shape[key]:
            raise ValueError(f"log key {key!r}: rows of shape {rows.shape[1:]} after {self._shape[key]}")
        if rows.dtype != self._dtype[key]:  # e.g. a wider unicode width
            self._dtype[key] = np.result_type(self._dtype[key], rows.dtype)
        self._pieces[key].append(rows)
        self._held[key] += rows.nbytes
        self._rows[key] += len(rows)
        if self.spill_dir is not None and self._held[key] > self.spill_bytes:
            self._spill(key)

    def _spill(self, key: str) -> None:
        """Replace the key's in-memory pieces by one chunk file."""
        spilled = [p for p in self._pieces[key] if isinstance(p, Path)]  # always before the held ones
        held = [p for p in self._pieces[key] if not isinstance(p, Path)]
        self.spill_dir.mkdir(parents=True, exist_ok=True)
        path = self.spill_dir / f"{self._files:06d}.npy"
        self._files += 1
        np.save(path, np.concatenate(held), allow_pickle=False)
        self._pieces[key] = [*spilled, path]
        self._held[key] = 0

    def _chunks(self, key: str) -> Iterator[np.ndarray]:
        """The key's pieces in order, in the log's dtype (a spilled chunk read back whole)."""
        for p in self._pieces[key]:
            a = np.load(p, allow_pickle=False) if isinstance(p, Path) else p
            yield np.ascontiguousarray(a, dtype=self._dtype[key])

    def arrays(self) -> dict[str, np.ndarray]:
        out = {key: np.concatenate(list(self._chunks(key))) for key in self._pieces}
        out.update(self._whole)
        return out

    def save(self, path: Path) -> None:
        """Write log.npz with sorted keys, byte-identical to save_npz(self.arrays())."""
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
            for key in sorted([*self._whole, *self._pieces]):
                if key in self._whole:
                    data = _whole(self._whole[key])
                    _member(zf, key, len(data), iter([data]), self._whole[key].dtype)
                    continue
                header = io.BytesIO()
                dtype, shape = self._dtype[key], (self._rows[key], *self._shape[key])
                np.lib.format.write_array_header_1_0(
                    header, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape})
                size = len(header.getvalue()) + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                _member(zf, key, size, iter([header.getvalue(), *(c.tobytes() for c in self._chunks(key))]), dtype)

    def close(self) -> None:
        """Delete the spilled chunks (the spill directory)."""
        if self.spill_dir is not None and self.spill_dir.exists():
            shutil.rmtree(self.spill_dir)


class NpzLog(Mapping):
    """A saved log.npz as a read-only mapping: each array read on first access, then kept."""

    def __init__(self, path: Path | str):
        self._z = np.load(Path(path), allow_pickle=False)
        self._read: dict[str, np.ndarray] = {}

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._read:
            self._read[key] = self._z[key]
        return self._read[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._z.files)

    def row_blocks(self, key: str, rows: int = 256) -> Iterator[np.ndarray]:
        """Array `key` a block of up to `rows` rows at a time, decompressed as it is read and
        kept nowhere: a pass over a long log without holding the array."""
        with self._z.zip.open(key + ".npy") as f:
            version = np.lib.format.read_magic(f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran_order, dtype = read_header(f)
            if fortran_order or not shape:
                raise ValueError(f"{key}: row blocks need a C-ordered array of at least one axis")
            row_bytes = int(np.prod(shape[1:], dtype=np.int64)) * dtype.itemsize
            for r0 in range(0, shape[0], rows):
                n = min(rows, shape[0] - r0)
                yield np.frombuffer(f.read(n * row_bytes), dtype=dtype).reshape(n, *shape[1:])

    def __len__(self) -> int:
        return len(self._z.files)

    def __contains__(self, key: object) -> bool:
        return key in self._z.files

    def close(self) -> None:
        self._z.close()

    def __enter__(self) -> "NpzLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def load_log(path: Path | str) -> dict[str, np.ndarray]:
    """All arrays of a log.npz (a run directory or the file itself) as a dict; RunError (one line)
    if the file is not a readable npz (truncated, corrupt)."""
    path = Path(path)
    if path.is_dir():
        path = path / "log.npz"
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh: closed even when np.load fails
            return {k: z[k] for k in z.files}
    except (ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise RunError(f"{path}: not a readable run log: {type(e).__name__}: {e}".splitlines()[0]) from None
