"""One training process per run folder: an exclusive ``flock`` on ``<run folder>/.lock``.

The lock belongs to the open file, so the operating system drops it when the process ends in any way (also
``kill -9``): a killed run never leaves the folder locked. The file holds the owner's pid for the refusal
message; it is never deleted (deleting it would let a second process lock a new file of the same name).
"""

from __future__ import annotations

import os

try:
    import fcntl
except ImportError:  # not POSIX: no locking
    fcntl = None

__all__ = ["RunLock", "LOCK_NAME"]

LOCK_NAME = ".lock"


class RunLock:
    """``with RunLock(folder):`` holds the folder's lock; raises ValueError if a live process holds it."""

    def __init__(self, folder: str):
        self.folder = os.path.abspath(folder)
        self.path = os.path.join(self.folder, LOCK_NAME)
        self._f = None

    def acquire(self) -> "RunLock":
        f = open(self.path, "a+")
        if fcntl is not None:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.seek(0)
                owner = f.read().strip()
                f.close()
                raise ValueError(f"{self.folder} is being written by another running python -m train"
                                 f"{f' (pid {owner})' if owner else ''}; wait for it to finish, stop it, or choose "
                                 f"another --out") from None
        f.seek(0)
        f.truncate()
        f.write(f"{os.getpid()}\n")
        f.flush()
        self._f = f
        return self

    def release(self) -> None:
        if self._f is not None:
            if fcntl is not None:
                fcntl.flock(self._f.fileno(), fcntl.LOCK_UN)
            self._f.close()
            self._f = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
