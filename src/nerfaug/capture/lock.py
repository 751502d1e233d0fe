"""Who may change a session: an advisory lock on `RUN/.lock` that the `nerfaug` commands which
change a session (`train`, `add`, `propose`) and `nerfaug serve` take before they open it, so two
writers never work on the same session at once (each would save over the other's steps).

The lock is `fcntl.flock` on Linux and macOS (released by the kernel when its process ends, even
when killed); where `fcntl` is missing (Windows) sessions are not locked. The file holds who has the
lock (`{"pid", "holder", "since"}`) so that a second writer can say whom it waits for. A command
waits for another command (one line says for whom; Ctrl-C stops waiting); a running service keeps
the sessions it has opened, so a command is refused at once with one line naming it.

    with command_scope():                      # the CLI: every lock taken inside is released at its end
        hold(run, "nerfaug train", wait=True)  # waits for another command, refused when a service holds it
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path

from nerfaug import runfiles
from nerfaug.capture.state import now
from nerfaug.errors import NerfaugError

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; sessions are not locked there
    fcntl = None

LOCK_FILE = ".lock"
SERVICE = "nerfaug serve"  # the holder name of a service: commands do not wait for it
POLL_S = 0.2


class SessionBusy(NerfaugError):
    """Another process is changing the session; the message names it (pid, command, since when)."""

    exit_code = 1


@dataclass
class SessionLock:
    """A held lock on one session's folder; `release()` (or the end of its process) frees it."""

    run_dir: Path
    handle: object | None

    def release(self) -> None:
        if self.handle is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self.handle.fileno(), fcntl.LOCK_UN)
            self.handle.close()
            self.handle = None

    def __enter__(self) -> SessionLock:
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def holder_of(run_dir: Path) -> dict:
    """Who last took the session's lock ({} when unknown): pid, holder, since."""
    try:
        data = json.loads(runfiles.read_text(run_dir, LOCK_FILE))
    except (OSError, ValueError):  # PathRefused too: a lock file leading outside is never read
        return {}
    return data if isinstance(data, dict) else {}


def describe(holder: dict) -> str:
    """'`nerfaug train` (pid 4242, since 2026-11-25T10:00:00+00:00)', or 'another process'."""
    if not holder.get("holder"):
        return "another process"
    return f"`{holder['holder']}` (pid {holder.get('pid', '?')}, since {holder.get('since', '?')})"


def try_lock(run_dir: Path, holder: str) -> SessionLock | None:
    """The session's lock if free now, else None (never waits)."""
    run_dir = Path(run_dir)
    if fcntl is None:
        return SessionLock(run_dir, None)
    handle = runfiles.open_lock(run_dir, LOCK_FILE)  # kept open while the lock is held
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        return None
    except BaseException:
        handle.close()
        raise
    handle.seek(0)
    handle.truncate()
    handle.write(json.dumps({"pid": os.getpid(), "holder": holder, "since": now()}))
    handle.flush()
    return SessionLock(run_dir, handle)


def acquire(
    run_dir: Path,
    holder: str,
    wait: bool = True,
    timeout: float | None = None,
    on_wait: Callable[[str], None] | None = None,
) -> SessionLock:
    """Take the session's lock for `holder` (e.g. "nerfaug train").

    Args:
        run_dir: the session's run folder (it must exist).
        holder: who takes it, shown to a second writer.
        wait: wait for another holder to finish (never for a service: `SERVICE` keeps its sessions).
        timeout: seconds to wait at most (None: until it is free).
        on_wait: called once with one line saying whom it waits for.

    Raises:
        SessionBusy: the lock is held and `wait` is False, the holder is a service, or `timeout` passed.
    """
    run_dir = Path(run_dir)
    deadline = None if timeout is None else time.monotonic() + timeout
    told = False
    while True:
        lock = try_lock(run_dir, holder)
        if lock is not None:
            return lock
        other = holder_of(run_dir)
        busy = f"{run_dir}: {describe(other)} is changing this session"
        if other.get("holder") == SERVICE:
            raise SessionBusy(f"{busy}; change it through the service's HTTP API, or stop the service first")
        if not wait or (deadline is not None and time.monotonic() >= deadline):
            raise SessionBusy(f"{busy}; try again when it has finished")
        if not told and on_wait is not None:
            on_wait(f"waiting for {busy.split(': ', 1)[1]} (Ctrl-C stops waiting)")
            told = True
        time.sleep(POLL_S)


_SCOPE: ContextVar[contextlib.ExitStack | None] = ContextVar("nerfaug_session_locks", default=None)


@contextlib.contextmanager
def command_scope() -> Iterator[None]:
    """Release every lock `hold` takes inside this block at its end (one CLI command)."""
    with contextlib.ExitStack() as stack:
        token = _SCOPE.set(stack)
        try:
            yield
        finally:
            _SCOPE.reset(token)


_HELD: dict[Path, SessionLock] = {}  # what `hold` took, by folder: a second `hold` in this process reuses it


def hold(run_dir: Path, holder: str, wait: bool = True, on_wait: Callable[[str], None] | None = None) -> SessionLock:
    """`acquire`, kept until the enclosing `command_scope` ends (else until the process ends); a
    session this process already holds this way is not waited for."""
    key = Path(run_dir).resolve()
    if key in _HELD and _HELD[key].handle is not None:
        return _HELD[key]
    lock = _HELD[key] = acquire(run_dir, holder, wait=wait, on_wait=on_wait)
    scope = _SCOPE.get()
    if scope is not None:
        scope.callback(_release, key)
    return lock


def _release(key: Path) -> None:
    lock = _HELD.pop(key, None)
    if lock is not None:
        lock.release()
