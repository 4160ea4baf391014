"""The run log: writing and reading `log.npz` bit-identically.

numpy's savez stamps the current time into the zip entries, so two identical runs would give
different files; `save_npz` writes the same arrays as an uncompressed-header, deflated zip with a
fixed timestamp and sorted keys, so the same seed gives the same bytes.
"""
from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

_EPOCH = (1980, 1, 1, 0, 0, 0)


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays to a .npz file (loadable with numpy.load) deterministically."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for key in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arrays[key]), allow_pickle=False)
            info = zipfile.ZipInfo(key + ".npy", date_time=_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


def load_log(path: Path | str) -> dict[str, np.ndarray]:
    """All arrays of a log.npz (a run directory or the file itself) as a dict."""
    path = Path(path)
    if path.is_dir():
        path = path / "log.npz"
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}
