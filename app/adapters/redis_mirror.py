"""A city's epoch state as this process last saw it in Redis, so that loading an epoch's state fetches only
what the mirror lacks (docs/DESIGN.md, "The state mirror").

The city's meta hash holds ``rev``, a token that every commit replaces, and ``sd:{c}:tasks:rev`` one that
every commit writing tasks and every task registration replaces. A mirror holds the counts and visit sets
it read or wrote at revision ``rev`` and the open tasks at ``tasks_rev``; the load script is asked only for
the keys the mirror lacks and answers ``stale`` (then everything is read) unless the city's revision and
version are still the mirror's, and the commit script reports whether the revisions it replaced were the
ones the mirror held: only then is the commit applied to the mirror (it then equals what Redis holds).
Likewise a task registration of this process, a transaction that watches the tasks' revision, adds the
tasks it wrote to the mirror when the mirror held the revision it replaced. An
empty revision (a city no commit has touched since its meta expired or was deleted) is never trusted.

Counts and visit sets expire in Redis (the retention): each entry keeps the monotonic time before which its
key cannot have expired (its TTL when read, the retention when written, less ``EXPIRY_MARGIN_S``) and is
fetched again after it. A key absent from Redis appears only through a commit, which changes the revision.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from services.model import DONE, IntervalKey, Task, TaskId, TaxiId, Visit

__all__ = [
    "CityMirror",
    "Held",
    "EXPIRY_MARGIN_S",
    "deadline_of",
    "Pairs",
    "CountEntry",
    "VisitEntry",
    "VisitKey",
]

EXPIRY_MARGIN_S = 5.0
"""An entry is fetched again this long before its key could expire in Redis."""

Pairs = frozenset[tuple[IntervalKey, int]]
VisitKey = tuple[IntervalKey, TaxiId]
CountEntry = tuple[float, dict[int, int]]  # (deadline, Lambda by cell)
VisitEntry = tuple[float, Pairs]  # (deadline, the (k, cell) pairs of one taxi and interval)


def deadline_of(now: float, pttl_ms: int) -> float:
    """The monotonic time until which a key read at ``now`` with ``PTTL`` ``pttl_ms`` is known to exist as
    read (absent or without a TTL: for good, until a write, which changes the revision)."""
    if pttl_ms < 0:
        return math.inf
    return now + pttl_ms / 1000.0 - EXPIRY_MARGIN_S


@dataclass(slots=True)
class CityMirror:
    """The counts, visit sets and open tasks of one city at revisions ``rev`` and ``tasks_rev``.

    Entries are never changed in place (a commit replaces them), so a load can hand them out; the mirror
    itself is read and changed under the store's lock only. ``tasks`` is ``None`` while the open tasks are
    unknown; ``floor``: the intervals before it are forgotten."""

    rev: str
    version: int
    counts: dict[IntervalKey, CountEntry] = field(default_factory=dict)
    visits: dict[VisitKey, VisitEntry] = field(default_factory=dict)
    tasks_rev: str = ""
    tasks: dict[TaskId, Task] | None = None
    floor: IntervalKey | None = None

    def count(self, k: IntervalKey, now: float) -> CountEntry | None:
        """Lambda of interval ``k`` by cell with its deadline, or ``None`` when not held (or about to
        expire)."""
        hit = self.counts.get(k)
        return hit if hit is not None and hit[0] > now else None

    def visit(self, k: IntervalKey, taxi: TaxiId, now: float) -> VisitEntry | None:
        """The (k, cell) pairs ``taxi`` is counted in during ``k`` with their deadline, or ``None`` when not
        held."""
        hit = self.visits.get((k, taxi))
        return hit if hit is not None and hit[0] > now else None

    def held_tasks(self) -> tuple[str, int]:
        """The tasks' revision and number the load script compares ('' when the tasks are unknown)."""
        return ("", 0) if self.tasks is None else (self.tasks_rev, len(self.tasks))

    def prune(self, oldest: IntervalKey) -> None:
        """Forget the intervals before ``oldest`` (epochs move forward: a rewound city reads them again)."""
        if self.floor is not None and oldest <= self.floor:
            return
        self.floor = oldest
        self.counts = {k: v for k, v in self.counts.items() if k >= oldest}
        self.visits = {kt: v for kt, v in self.visits.items() if kt[0] >= oldest}

    def apply_visits(self, visits: Sequence[Visit], now: float, deadline: float) -> None:
        """The commit script's visits, sent at ``now``: a cell new to a (taxi, interval) set counts once
        more, and every key written lives until ``deadline``. A set the mirror does not hold makes its
        interval's counts unknown (whether a visit was new is unknown). Each entry a commit changes is
        copied once, whatever the number of its visits."""
        counts, sets = self.counts, self.visits
        new: dict[VisitKey, set[tuple[IntervalKey, int]]] = {}  # per held set: the pairs it gains
        grown: dict[IntervalKey, dict[int, int]] = {}  # per interval: cell -> sets that gained it
        unknown: set[IntervalKey] = set()
        for v in visits:
            key = (v.interval, v.taxi_id)
            have = sets.get(key)
            if have is None or not have[0] > now:
                sets.pop(key, None)
                unknown.add(v.interval)
                continue
            pair = (v.interval, int(v.cell))
            gained = new.setdefault(key, set())
            if pair in have[1] or pair in gained:
                continue
            gained.add(pair)
            cells = grown.setdefault(v.interval, {})
            cells[pair[1]] = cells.get(pair[1], 0) + 1
        for key, gained in new.items():
            have = sets[key]
            sets[key] = (deadline, have[1] | gained if gained else have[1])
        for k, add in grown.items():
            hit = counts.get(k)
            if k in unknown or hit is None:
                continue
            if not hit[0] > now:
                counts.pop(k)
                continue
            cells = dict(hit[1])
            for cell, n in add.items():
                cells[cell] = cells.get(cell, 0) + n
            counts[k] = (deadline, cells)
        for k in unknown:
            counts.pop(k, None)

    def apply_tasks(self, updates: Iterable[Task]) -> None:
        """A commit's task updates (a finished task leaves the open tasks, others are upserted) or a
        registration's new tasks."""
        if self.tasks is None:
            return
        tasks = dict(self.tasks)  # a load may be reading the one it was handed
        for t in updates:
            if t.status in DONE:
                tasks.pop(t.id, None)
            else:
                tasks[t.id] = t
        self.tasks = tasks


@dataclass(frozen=True, slots=True)
class Held:
    """What a load asks for and what the mirror held of it when the load was sent."""

    mirror: CityMirror | None
    rev: str
    version: int
    tasks_rev: str
    n_tasks: int
    tasks: dict[TaskId, Task] | None
    counts: list[CountEntry | None]
    visits: list[VisitEntry | None]

    @classmethod
    def nothing(cls, n_counts: int, n_visits: int) -> Held:
        """Nothing held (no mirror, or one found stale): every key is read."""
        return cls(None, "", 0, "", 0, None, [None] * n_counts, [None] * n_visits)
