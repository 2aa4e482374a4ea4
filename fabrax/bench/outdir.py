"""A run's output folder, claimed before any work: writable, not another run's, never a finished
run's unless the run resumes it.

`claim(out, resume)` creates the folder, proves it writable, takes its lock file (`.fabrax.lock`
with the owner's pid, created exclusively, so that two runs started into one folder cannot both
write it) and refuses a folder that holds an earlier run's results or checkpoint unless
`resume` (whose settings the runner then compares). A lock left by a run that died (its pid is
gone) is taken over. Every refusal is one line naming `out=`.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

LOCK = ".fabrax.lock"
EARLIER = ("results.json", "solutions.pkl")  # what a finished or interrupted run leaves


class OutDirError(Exception):
    """The output folder cannot be used (one line, naming it)."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _take_lock(path: Path) -> None:
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(path.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and _alive(pid):
                raise OutDirError(f"out={path.parent} is being written by another run (pid {pid}); use another out=") from None
            path.unlink(missing_ok=True)  # a dead run's lock
            continue
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        return
    raise OutDirError(f"out={path.parent}: could not take its lock file {path.name}")


@contextlib.contextmanager
def claim(out: Path, resume: bool = False):
    """Hold `out` for one run (see the module docstring); the lock is released on exit."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutDirError(f"out={out} is a file, not a folder; use another out=")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".fabrax-write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise OutDirError(f"out={out} is not writable: {e.strerror or e}") from None
    lock = out / LOCK
    _take_lock(lock)
    try:
        earlier = [name for name in EARLIER if (out / name).exists()]
        if earlier and not resume:
            raise OutDirError(
                f"out={out} holds an earlier run ({', '.join(earlier)}); use another out=, or resume=true to continue it with the same settings"
            )
        yield out
    finally:
        lock.unlink(missing_ok=True)
