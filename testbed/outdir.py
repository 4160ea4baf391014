"""Output directories: the testbed only ever replaces what it can prove it wrote.

Every directory the testbed writes (run, sweep, reproduction, demo) holds a marker file `.testbed`
naming the testbed and its version, and `provenance.json` (how it was made: testbed.provenance).
An output location `OUT` is

- refused, `--force` or not: the empty path, the working directory or one of its parents, the home
  directory, `/`, a symbolic link, a file, a non-empty directory without the marker;
- refused without `--force`: a directory with the marker (an earlier output);
- accepted: a path that does not exist yet, an empty directory.

Whatever the output, it never overlaps an input of the command (`apart`): an output that is, contains
or lies inside a file or directory the command reads is refused, `--force` or not.

Writing takes an exclusive lock (`.OUT.testbed-lock` beside OUT, an flock released by the kernel when
its holder dies; it names the holder's pid and command), writes into a temporary sibling
`.OUT.testbed-tmp.PID/` and renames it to OUT only when complete. Replacing renames the old OUT aside
(`.OUT.testbed-old.PID/`) and deletes it only after the new one is in place. A temporary sibling whose
pid is dead (left by SIGKILL) is removed by the next command writing OUT; an old OUT set aside by a
command killed mid-replacement is restored.
"""
from __future__ import annotations

import fcntl
import json
import math
import os
import shlex
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from testbed import __version__, provenance
from testbed.errors import RunError, UsageError
from testbed.interrupt import Interrupted, signals_held

MARKER = ".testbed"
WRITER = "testbed"
TMP_TAG, OLD_TAG, LOCK_TAG = ".testbed-tmp.", ".testbed-old.", ".testbed-lock"


def out_arg(text: str) -> Path:
    """argparse `type` for an output path: the empty string is refused (it would mean `.`)."""
    if not text.strip():
        raise UsageError(f"--out {text!r}: an empty path is not an output location")
    return Path(text)


def command() -> str:
    """This process's command line, as the lock names it."""
    return shlex.join(["testbed", *sys.argv[1:]]) if sys.argv and sys.argv[0] else "testbed"


def marker(path: Path) -> dict | None:
    """The marker of a directory the testbed wrote ({"written_by", "version", "kind"}), else None."""
    try:
        m = json.loads((Path(path) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return m if isinstance(m, dict) and m.get("written_by") == WRITER else None


def write_marker(path: Path, kind: str) -> None:
    write_json(Path(path) / MARKER, {"written_by": WRITER, "version": __version__, "kind": kind})


def check(out: Path, *, force: bool) -> None:
    """Raise RunError unless `out` may be written (see the module docstring); touches nothing."""
    out = Path(out)
    if str(out) in ("", "."):
        raise RunError(f"{str(out)!r}: the working directory is never an output location")
    real = out.resolve()
    cwd = Path.cwd().resolve()
    if real == cwd or real in cwd.parents:
        raise RunError(f"{out}: is the working directory or one of its parents; refusing to write there, --force or not")
    if real == Path.home().resolve() or real == Path(real.anchor):
        raise RunError(f"{out}: is the home directory or the root; refusing to write there, --force or not")
    if out.is_symlink():
        raise RunError(f"{out}: is a symbolic link; refusing to replace it, --force or not")
    if not out.exists():
        return
    if not out.is_dir():
        raise RunError(f"{out}: exists and is not a directory; refusing to replace it, --force or not")
    if not any(out.iterdir()):
        return
    if marker(out) is None:
        raise RunError(f"{out}: is not empty and was not written by the testbed (no {MARKER} marker); "
                       "refusing to replace it, --force or not")
    if not force:
        raise RunError(f"{out}: already exists (use --force to replace it)")


def apart(out: Path, inputs: Iterable[Path]) -> None:
    """Raise UsageError if `out` is, contains or lies inside one of `inputs` (files or directories
    the command reads), compared after resolving symbolic links and relative paths; touches nothing."""
    real = Path(out).resolve()
    for path in inputs:
        inp = Path(path).resolve()
        how = "is" if real == inp else "contains" if real in inp.parents else "lies inside" if inp in real.parents else ""
        if how:
            raise UsageError(f"--out {out}: {how} the input {path}; refusing to write there, --force or not")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _tagged_pid(name: str, stem: str, tag: str) -> int | None:
    """The pid in a sibling named `.STEM{tag}PID[...]`, else None."""
    prefix = f".{stem}{tag}"
    if not name.startswith(prefix):
        return None
    digits = name[len(prefix):].split(".")[0]
    return int(digits) if digits.isdigit() else None


def clean_stale(out: Path) -> None:
    """Remove temporary siblings of `out` left by dead processes; restore an old `out` set aside."""
    out = Path(out)
    if not out.parent.is_dir():
        return
    for entry in sorted(out.parent.iterdir()):
        for tag in (OLD_TAG, TMP_TAG):
            pid = _tagged_pid(entry.name, out.name, tag)
            if pid is None or pid == os.getpid() or _pid_alive(pid):
                continue
            if tag == OLD_TAG and not out.exists() and marker(entry) is not None:
                entry.rename(out)
                print(f"testbed: restored {out} (set aside by pid {pid}, which died while replacing it)", file=sys.stderr)
            elif entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)
                print(f"testbed: removed {entry} (left by pid {pid}, which died)", file=sys.stderr)
            elif entry.is_file():
                entry.unlink(missing_ok=True)
                print(f"testbed: removed {entry} (left by pid {pid}, which died)", file=sys.stderr)


def remove_unheld_locks(directory: Path, wait_s: float = 0.0) -> None:
    """Remove the lock files in `directory` that no process holds, with the temporary directories of
    their outputs: left by a writer killed before it could release its lock or remove its temporary
    directory (a Ray task cancelled by force). A lock is waited for up to wait_s seconds (a killed
    writer may take a moment to die); one still held then is left alone with its temporary
    directory; a writer taking one at the same time sees its file gone and takes a new one
    (Lock.acquire)."""
    deadline = time.monotonic() + wait_s
    for path in sorted(Path(directory).glob(f".*{LOCK_TAG}")):
        try:
            fd = os.open(path, os.O_RDWR)
        except OSError:
            continue
        try:
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise
                    time.sleep(0.05)
            name = path.name[1:-len(LOCK_TAG)]  # .OUT.testbed-lock -> OUT
            for tmp in sorted(path.parent.glob(f".{name}{TMP_TAG}*")):
                if tmp.is_dir() and not tmp.is_symlink():
                    shutil.rmtree(tmp, ignore_errors=True)
            path.unlink(missing_ok=True)
        except BlockingIOError:
            pass  # held: its writer is alive
        finally:
            os.close(fd)


class Lock:
    """Exclusive right to write `out`: an flock on `.OUT.testbed-lock` beside it (see the module docstring)."""

    def __init__(self, out: Path):
        self.path = Path(out).parent / f".{Path(out).name}{LOCK_TAG}"
        self.fd: int | None = None

    def acquire(self) -> None:
        for _ in range(20):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 4096).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise RunError(f"{self.path.parent / self.path.name[1:-len(LOCK_TAG)]}: is being written by {holder}; "
                               "try again when it has finished") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:  # not a lock file its previous holder unlinked while we waited
                os.ftruncate(fd, 0)
                os.write(fd, f"pid {os.getpid()} ({command()})\n".encode())
                self.fd = fd
                return
            os.close(fd)
        raise RunError(f"{self.path}: could not take the lock")

    def release(self) -> None:
        if self.fd is not None:
            self.path.unlink(missing_ok=True)
            os.close(self.fd)
            self.fd = None


def _missing_parents(path: Path) -> list[Path]:
    missing = []
    for p in Path(path).absolute().parents:
        if p.exists():
            break
        missing.append(p)
    return missing


class Output:
    """`with Output(out, kind=...) as o:` write into `o.path`, then `o.commit()`.

    Without a commit (an exception, a signal) the temporary directory is removed and `out` is
    untouched. resume=True: an existing `out` of the same kind is written in place (no temporary
    directory; every file in it must be written atomically, see `write_text`).
    """

    def __init__(self, out: Path, *, kind: str, force: bool = False, resume: bool = False):
        self.out, self.kind, self.force = Path(out), kind, force
        self.resume = resume and self.out.is_dir() and not self.out.is_symlink() and marker(self.out) is not None
        if self.resume and marker(self.out).get("kind") != kind:
            raise RunError(f"{self.out}: is a {marker(self.out).get('kind')} directory, not a {kind}; cannot resume it")
        self.existed = self.out.exists()
        self.lock = Lock(self.out)
        self.path = self.out
        self._created: list[Path] = []
        self.done = False
        self.started = provenance.start()

    def __enter__(self) -> "Output":
        if not self.resume:
            check(self.out, force=self.force)
        try:
            self._created = _missing_parents(self.out)
            make_parent(self.out)
            self.lock.acquire()
        except OSError as e:
            self._remove_created()
            raise RunError(os_reason(self.out, e)) from None
        try:
            clean_stale(self.out)
            if not self.resume:
                self.path = self.out.parent / f".{self.out.name}{TMP_TAG}{os.getpid()}"
                self.path.mkdir()
                write_marker(self.path, self.kind)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def commit(self) -> None:
        """Write provenance.json (testbed.provenance), then put the finished directory at `out`
        (replacing an earlier output, now proven ours)."""
        if not self.done:
            write_json(self.path / provenance.PROVENANCE, provenance.record(self.started, output=self.kind))
        if self.resume or self.done:
            self.done = True
            return
        check(self.out, force=self.force)  # again: it may have changed while we were writing
        with signals_held():
            aside = None
            if self.out.is_dir() and marker(self.out) is None:  # empty, checked above
                self.out.rmdir()
            elif self.out.exists():
                aside = self.out.parent / f".{self.out.name}{OLD_TAG}{os.getpid()}"
                self.out.rename(aside)
            self.path.rename(self.out)
            self.path, self.done = self.out, True
        if aside is not None:
            shutil.rmtree(aside)

    def _remove_created(self) -> None:
        for p in self._created:  # innermost first
            try:
                p.rmdir()
            except OSError:
                break

    def __exit__(self, typ: type | None, exc: BaseException | None, tb: object) -> None:
        try:
            if not self.done and not self.resume and self.path != self.out:
                shutil.rmtree(self.path, ignore_errors=True)
        finally:
            self.lock.release()
            if not self.done and not self.existed:
                self._remove_created()
        if isinstance(exc, Interrupted) and not self.done and str(self.path) in exc.detail:  # what it kept is gone too
            raise Interrupted(exc.signum, f"{self.out} not written; temporary files removed") from None
        if isinstance(exc, OSError):  # the user's path and the OS's reason, never the temporary name
            raise RunError(os_reason(self.out, exc).replace(str(self.path), str(self.out))) from None
        if isinstance(exc, RunError) and self.path != self.out and str(self.path) in str(exc):
            raise RunError(str(exc).replace(str(self.path), str(self.out))) from None


def os_reason(out: Path, e: OSError) -> str:
    """One line: the output path, the OS's reason, and the file it concerned when that is another."""
    where = f" ({e.filename})" if e.filename and str(e.filename) != str(out) else ""
    return f"{out}: {e.strerror or e}{where}"


def make_parent(out: Path) -> None:
    """Create the parent directories of `out`; a file in the way is named (not `File exists`)."""
    for p in reversed(Path(out).absolute().parents):
        if p.exists() and not p.is_dir():
            raise RunError(f"{out}: {p} is a file, not a directory")
    Path(out).parent.mkdir(parents=True, exist_ok=True)


def write_text(path: Path, text: str) -> None:
    """Write a file atomically (a temporary sibling renamed over it)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}{TMP_TAG}{os.getpid()}")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _nonfinite(obj: object, key: str = "") -> list[str]:
    """Dotted paths of the NaN/inf floats in nested dicts and lists."""
    if isinstance(obj, float):
        return [] if math.isfinite(obj) else [key or "(top level)"]
    if isinstance(obj, dict):
        return [p for k, v in obj.items() for p in _nonfinite(v, f"{key}.{k}" if key else str(k))]
    if isinstance(obj, (list, tuple)):
        return [p for i, v in enumerate(obj) for p in _nonfinite(v, f"{key}[{i}]")]
    return []


def write_json(path: Path, obj: object) -> None:
    """Strict JSON (no NaN or Infinity: a score that cannot exist is null with a reason beside it)."""
    bad = _nonfinite(obj)
    if bad:
        raise ValueError(f"{path}: non-finite numbers at {', '.join(bad)}: write null and a reason instead")
    write_text(path, json.dumps(obj, indent=2, allow_nan=False) + "\n")


def check_new_file(out: Path, *, force: bool) -> None:
    """Refuse a file output that is a directory, or that exists unless force (RunError)."""
    if out.is_dir():
        raise RunError(f"{out}: is a directory; give a file name")
    if out.exists() and not force:
        raise RunError(f"{out}: already exists (use --force to replace it)")


@contextmanager
def new_file(out: Path, *, force: bool, suffix: str = "") -> Iterator[Path]:
    """Write one file: yields a temporary sibling path (ending in `suffix`, created empty, so a folder
    that takes no new file is refused before the writer starts), put at `out` on success.

    Refuses an existing `out` unless force (checked first and again, atomically, at the end).
    """
    out = Path(out)
    check_new_file(out, force=force)
    try:
        make_parent(out)
    except OSError as e:
        raise RunError(os_reason(out, e)) from None
    clean_stale(out)
    tmp = out.with_name(f".{out.name}{TMP_TAG}{os.getpid()}{suffix}")
    try:
        open(tmp, "xb").close()  # the folder takes a new file: known before any writer starts
    except OSError as e:
        raise RunError(f"{out}: {e.strerror or e}") from None
    try:
        yield tmp
        if force:
            os.replace(tmp, out)
        else:
            try:
                os.link(tmp, out)  # fails if out appeared meanwhile: never overwritten
            except FileExistsError:
                raise RunError(f"{out}: already exists (use --force to replace it)") from None
    finally:
        tmp.unlink(missing_ok=True)
