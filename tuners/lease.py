"""One writer per study: a lease row with a heartbeat beside the Optuna tables.

A tuning run holds the lease of its study while it writes (:class:`StudyLease`). The
lease lives in a table of its own, ``tuner_leases`` (``study_name`` primary key,
``holder`` = ``host:pid/token``, ``heartbeat`` and ``started`` as Unix times), in the
same database as the study, created through SQLAlchemy on the storage's engine
(Optuna's ``RDBStorage`` offers no compare-and-swap on study attributes: its
``set_study_system_attr`` is an unconditional upsert). Taking the lease is one
``INSERT`` — atomic through the primary key, so of two writers starting at the same
instant exactly one gets it. A held lease is refused with :class:`StudyLockedError`
naming the holder, unless it is stale: its holder is a process of this host that no
longer exists, or its heartbeat is older than ``stale_after_s``. A stale lease is taken
over by a conditional ``UPDATE`` on the old holder and heartbeat (again one winner).
A daemon thread renews the heartbeat every ``heartbeat_s``; if another process took
the lease over meanwhile, :meth:`StudyLease.check` raises.

Storages other than an RDB (in memory: one process only) get no lease.
"""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from typing import Any

import sqlalchemy as sa

__all__ = ["HEARTBEAT_S", "STALE_AFTER_S", "StudyLease", "StudyLockedError", "lease_holder"]

HEARTBEAT_S = 10.0
STALE_AFTER_S = 60.0
_META = sa.MetaData()
LEASES = sa.Table(
    "tuner_leases",
    _META,
    sa.Column("study_name", sa.String(512), primary_key=True),
    sa.Column("holder", sa.String(512), nullable=False),
    sa.Column("heartbeat", sa.Float, nullable=False),
    sa.Column("started", sa.Float, nullable=False),
)


class StudyLockedError(ValueError):
    """Another live process writes the study."""


def _engine(storage: Any) -> sa.engine.Engine | None:
    return getattr(storage, "engine", None)


def _alive_here(holder: str) -> bool | None:
    """Whether the holder's process exists (None: it runs on another host)."""
    host, _, rest = holder.partition(":")
    if host != socket.gethostname():
        return None
    try:
        pid = int(rest.split("/", 1)[0])
    except ValueError:
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True


def lease_holder(storage: Any, study_name: str) -> dict[str, Any] | None:
    """The lease row of a study (holder, heartbeat age, live) or None."""
    engine = _engine(storage)
    if engine is None:
        return None
    _META.create_all(engine, checkfirst=True)
    with engine.connect() as con:
        row = con.execute(sa.select(LEASES).where(LEASES.c.study_name == study_name)).first()
    if row is None:
        return None
    age = time.time() - float(row.heartbeat)
    alive = _alive_here(row.holder)
    live = (alive is not False) and age <= STALE_AFTER_S
    return {"holder": row.holder.split("/", 1)[0], "age_s": age, "live": live}


class StudyLease:
    """The write lease of ``study_name`` in ``storage`` (see module doc).

    Use as a context manager or call :meth:`acquire` / :meth:`release`.
    """

    def __init__(
        self,
        storage: Any,
        study_name: str,
        *,
        heartbeat_s: float = HEARTBEAT_S,
        stale_after_s: float = STALE_AFTER_S,
    ) -> None:
        self.engine = _engine(storage)
        self.study_name = study_name
        self.heartbeat_s = float(heartbeat_s)
        self.stale_after_s = float(stale_after_s)
        self.holder = f"{socket.gethostname()}:{os.getpid()}/{uuid.uuid4().hex[:8]}"
        self.lost = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.held = False

    # ---------------------------------------------------------------- acquire
    def acquire(self) -> StudyLease:
        if self.engine is None or self.held:
            return self
        _META.create_all(self.engine, checkfirst=True)
        for _ in range(3):  # insert; else take over a stale row; else refuse
            now = time.time()
            try:
                with self.engine.begin() as con:
                    con.execute(
                        sa.insert(LEASES).values(
                            study_name=self.study_name,
                            holder=self.holder,
                            heartbeat=now,
                            started=now,
                        )
                    )
                break
            except sa.exc.IntegrityError:
                pass
            with self.engine.connect() as con:
                row = con.execute(
                    sa.select(LEASES).where(LEASES.c.study_name == self.study_name)
                ).first()
            if row is None:  # released in between: try the insert again
                continue
            age = now - float(row.heartbeat)
            if _alive_here(row.holder) is not False and age <= self.stale_after_s:
                raise StudyLockedError(
                    f"study {self.study_name!r} is being written by {row.holder.split('/')[0]} "
                    f"(heartbeat {age:.0f} s ago); wait for that run to end or stop it"
                )
            with self.engine.begin() as con:
                res = con.execute(
                    sa.update(LEASES)
                    .where(
                        LEASES.c.study_name == self.study_name,
                        LEASES.c.holder == row.holder,
                        LEASES.c.heartbeat == row.heartbeat,
                    )
                    .values(holder=self.holder, heartbeat=now, started=now)
                )
            if res.rowcount == 1:
                break
        else:
            raise StudyLockedError(
                f"study {self.study_name!r}: another process took its lease at the same time"
            )
        self.held = True
        self._thread = threading.Thread(target=self._beat, name="tuner-lease", daemon=True)
        self._thread.start()
        return self

    def _beat(self) -> None:
        while not self._stop.wait(self.heartbeat_s):
            try:
                with self.engine.begin() as con:
                    res = con.execute(
                        sa.update(LEASES)
                        .where(
                            LEASES.c.study_name == self.study_name, LEASES.c.holder == self.holder
                        )
                        .values(heartbeat=time.time())
                    )
                if res.rowcount == 0:
                    self.lost = True
                    return
            except sa.exc.SQLAlchemyError:  # a busy database: try at the next beat
                continue

    def check(self) -> None:
        """Raise :class:`StudyLockedError` if another process took the lease over."""
        if self.lost:
            raise StudyLockedError(
                f"study {self.study_name!r}: the write lease was taken over by another process "
                "(this run stalled longer than the stale limit); stopping"
            )

    # ---------------------------------------------------------------- release
    def release(self) -> None:
        if not self.held:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        try:
            with self.engine.begin() as con:
                con.execute(
                    sa.delete(LEASES).where(
                        LEASES.c.study_name == self.study_name, LEASES.c.holder == self.holder
                    )
                )
        except sa.exc.SQLAlchemyError:  # the row then goes stale and is taken over
            pass
        self.held = False

    def __enter__(self) -> StudyLease:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
