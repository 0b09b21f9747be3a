"""Redis ``Store``: one Lua script commits an epoch, another reads its state (the scripts are the files of
``app/adapters/lua/``, read at import); other reads are MULTI/EXEC snapshots (keys: docs/DESIGN.md).

Every key of a city carries the hash tag ``{city}``, so on a Redis Cluster (``mode="cluster"``, redis-py's
cluster client) all of a city's keys share one slot: each script and transaction runs on one node."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from collections.abc import Set as AbstractSet
from contextlib import contextmanager
from importlib import resources
from typing import Any, Literal, TypeVar, cast
from urllib.parse import urlsplit

import orjson
import redis
from redis.backoff import ExponentialBackoff
from redis.cluster import RedisCluster
from redis.commands.core import Script
from redis.exceptions import ClusterError, RedisClusterException, TryAgainError, WatchError
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError
from redis.retry import Retry

from app.adapters.codec import (
    check_fleet_record,
    classify_tasks,
    fleet_record_from_json,
    fleet_record_to_json,
    format_time,
    new_lock_token,
    solve_request_from_json,
    solve_request_to_json,
    task_from_json,
    task_to_json,
    worker_beat_from_json,
    worker_beat_to_json,
)
from app.adapters.redis_client import redis_client
from app.adapters.redis_mirror import (
    EXPIRY_MARGIN_S,
    CityMirror,
    CountEntry,
    Held,
    Pairs,
    VisitEntry,
    VisitKey,
    deadline_of,
)
from app.ports import (
    CityState,
    CommitResult,
    EnqueueResult,
    EpochCommit,
    FleetRecord,
    PublishResult,
    PutTasksResult,
    RewindResult,
    SolveRequest,
    StoredEpoch,
    StoreUnavailable,
    WorkerBeat,
)
from services.model import DONE, IntervalKey, Task, TaskId, TaxiId

__all__ = [
    "RedisStore",
    "RedisMode",
    "COMMIT_EPOCH_LUA",
    "REWIND_LUA",
    "PUBLISH_RECOMMENDATION_LUA",
    "RELEASE_LOCK_LUA",
    "ENQUEUE_SOLVE_LUA",
    "WORKER_BEAT_LUA",
]


def _lua(name: str) -> str:
    """The Lua script ``app/adapters/lua/<name>.lua`` (shipped with the package), read once at import."""
    return (resources.files("app.adapters") / "lua" / f"{name}.lua").read_text(encoding="utf-8")


COMMIT_EPOCH_LUA = _lua("commit_epoch")

REWIND_LUA = _lua("rewind")

PUBLISH_RECOMMENDATION_LUA = _lua("publish_recommendation")

RELEASE_LOCK_LUA = _lua("release_lock")

ENQUEUE_SOLVE_LUA = _lua("enqueue_solve")

WORKER_BEAT_LUA = _lua("worker_beat")


LOAD_STATE_LUA = _lua("load_state")


RedisMode = Literal["standalone", "cluster"]

_E = TypeVar("_E")
_K = TypeVar("_K")

_SCRIPTS = {
    "commit": COMMIT_EPOCH_LUA,
    "rewind": REWIND_LUA,
    "publish": PUBLISH_RECOMMENDATION_LUA,
    "release": RELEASE_LOCK_LUA,
    "enqueue": ENQUEUE_SOLVE_LUA,
    "beat": WORKER_BEAT_LUA,
    "load_state": LOAD_STATE_LUA,
}

_UNREACHABLE = (RedisConnectionError, RedisTimeoutError, RedisClusterException, ClusterError, TryAgainError)


class RedisStore:
    """``Store`` on a Redis server or a Redis Cluster; every connection failure surfaces as
    ``StoreUnavailable``."""

    def __init__(
        self,
        url: str,
        prefix: str = "sd",
        *,
        socket_timeout_s: float = 2.0,
        mode: RedisMode = "standalone",
    ) -> None:
        """Connect lazily to ``url`` (in cluster mode: any node of the cluster); keys are
        ``<prefix>:{<city>}:...``. ``socket_timeout_s`` bounds every connect, read and write (the API also
        bounds how many calls are in flight: ``app.adapters.bounded``)."""
        if not prefix or "{" in prefix or "}" in prefix:
            raise ValueError(f"invalid key prefix {prefix!r}")
        self._prefix = prefix
        self._url = url
        self._mode: RedisMode = mode
        self._timeout_s = socket_timeout_s
        parts = urlsplit(url)
        # no password in messages
        self._where = f"{mode} Redis at {parts.hostname}:{parts.port or 6379}"
        self._connect_lock = threading.Lock()
        self._conn: redis.Redis | RedisCluster | None = None
        self._scripts: dict[str, Script] = {}
        self._mirror_lock = threading.Lock()
        self._mirrors: dict[str, CityMirror] = {}  # by city (app/adapters/redis_mirror.py)
        self._task_cache: dict[str, dict[str, Task]] = {}  # by city: the open tasks' JSON -> task
        if mode == "standalone":
            self._connect()  # redis.Redis connects on first use anyway

    def _connect(self) -> redis.Redis | RedisCluster:
        """The client (a cluster client discovers the slots when made: made on first use, retried after a
        failure, so a cluster that is down at start-up is a 503 and not a crash)."""
        with self._connect_lock:
            if self._conn is not None:
                return self._conn
            conn: redis.Redis | RedisCluster
            if self._mode == "cluster":  # the options of redis_client, which makes the standalone one
                conn = RedisCluster.from_url(
                    self._url,
                    decode_responses=True,
                    socket_timeout=self._timeout_s,
                    socket_connect_timeout=self._timeout_s,
                    retry=Retry(ExponentialBackoff(cap=0.05, base=0.01), 1),
                )
            else:
                conn = redis_client(self._url, socket_timeout_s=self._timeout_s)
            self._scripts = {name: conn.register_script(lua) for name, lua in _SCRIPTS.items()}
            self._conn = conn
            return conn

    @property
    def _client(self) -> Any:
        # Any: redis.Redis and RedisCluster share the commands used here, not a typed base
        return self._conn if self._conn is not None else self._connect()

    def _eval(self, script: str, keys: Sequence[str], args: Sequence[str]) -> Any:
        """Run one of ``_SCRIPTS`` (EVALSHA, loading it first when the server lacks it)."""
        self._client  # noqa: B018 - connects and registers the scripts on first use
        return self._scripts[script](keys=list(keys), args=list(args))

    @property
    def mode(self) -> RedisMode:
        """``standalone`` or ``cluster``."""
        return self._mode

    # -- keys -----------------------------------------------------------------------------------------

    @property
    def prefix(self) -> str:
        """The key prefix (``sd`` by default)."""
        return self._prefix

    def _key(self, city: str, *parts: str) -> str:
        if not city or "{" in city or "}" in city:
            raise ValueError(f"invalid city name {city!r}")
        return ":".join((self._prefix, "{" + city + "}", *parts))

    @contextmanager
    def _guard(self, doing: str) -> Iterator[None]:
        try:
            yield
        except _UNREACHABLE as exc:
            raise StoreUnavailable(f"{self._where} is unreachable while {doing}: {exc}") from exc

    # -- the port -------------------------------------------------------------------------------------

    def ping(self) -> None:
        """Raise ``StoreUnavailable`` unless the server answers PING."""
        with self._guard("pinging"):
            self._client.ping()

    def get_epoch(self, city: str, epoch_id: str) -> StoredEpoch | None:
        """The stored record of an epoch, if any."""
        key = self._key(city, "epoch", epoch_id)
        with self._guard("reading an epoch record"):
            reply = cast(list[Any], self._client.hmget(key, ["hash", "time", "response"]))
        body_hash, time_s, response = reply
        if body_hash is None:
            return None
        return StoredEpoch(epoch_id, body_hash, float(time_s), response)

    def load_state(
        self,
        city: str,
        intervals: Sequence[IntervalKey],
        taxi_ids: Sequence[TaxiId],
        *,
        visits_from: IntervalKey | None = None,
    ) -> CityState:
        """Version, last epoch, counts, visits and tasks read by one script (``LOAD_STATE_LUA``: a consistent
        snapshot, and one reply per visit set where a pipeline of SMEMBERS paid redis-py ~20 us a command).
        With a mirror of the city (``CityMirror``) the script reads only the keys it lacks, and everything
        again when the city's revision is no longer the mirror's."""
        ks = list(dict.fromkeys(intervals))
        vks = ks if visits_from is None else [k for k in ks if k >= visits_from]
        taxis = list(dict.fromkeys(taxi_ids))
        pairs = [(k, taxi) for taxi in taxis for k in vks]
        now = time.monotonic()
        held = self._held(city, ks, pairs, now)
        replies = self._read_state(city, ks, pairs, held)
        if replies[2] == "stale":
            held = Held.nothing(len(ks), len(pairs))
            replies = self._read_state(city, ks, pairs, held)
        version, last_time, last_epoch, rev = replies[0]
        read = _Read(rev or "", replies[1] or "", int(version or 0), now, replies[3:])
        counts = read.entries(held.counts, ks, _count_entry)
        sets = read.entries(held.visits, pairs, _visit_entry)
        tasks = held.tasks if replies[2] is None else self._decode_open(city, replies[2])
        assert tasks is not None  # the script leaves them out only when the mirror's are current
        self._remember(city, held, read, (ks, counts), (pairs, sets), tasks)
        found: dict[TaxiId, list[Pairs]] = {taxi: [] for taxi in taxis}
        for (_, taxi), (_, cells) in zip(pairs, sets, strict=True):
            if cells:
                found[taxi].append(cells)
        # the one frozen set of a taxi counted in one interval only (the common case) is handed out as it is
        visited: dict[TaxiId, AbstractSet[tuple[IntervalKey, int]]] = {
            taxi: sets_[0] if len(sets_) == 1 else frozenset().union(*sets_) for taxi, sets_ in found.items()
        }
        return CityState(
            version=read.version,
            last_epoch_id=last_epoch,
            last_epoch_time_s=None if last_time is None else float(last_time),
            counts={k: dict(cells) for k, (_, cells) in zip(ks, counts, strict=True)},
            visited=visited,
            tasks=[tasks[i] for i in sorted(tasks)],
        )

    def _read_state(self, city: str, ks: list[IntervalKey], pairs: list[VisitKey], held: Held) -> list[Any]:
        """The load script's reply for the keys ``held`` lacks (``LOAD_STATE_LUA``)."""
        tag = self._key(city)
        keys = [f"{tag}:meta", f"{tag}:tasks", f"{tag}:tasks:rev"]
        keys += [_count_key(tag, k) for k, have in zip(ks, held.counts, strict=True) if have is None]
        n_counts = len(keys) - 3
        keys += [
            _visit_key(tag, k, t) for (k, t), have in zip(pairs, held.visits, strict=True) if have is None
        ]
        args = [str(n_counts), held.rev, held.tasks_rev, str(held.n_tasks), str(held.version)]
        try:
            with self._guard("loading city state"):
                return cast(list[Any], self._eval("load_state", keys, args))
        except BaseException:
            self._forget(city)
            raise

    # -- the state mirror (app/adapters/redis_mirror.py) ------------------------------------------------

    def _held(self, city: str, ks: list[IntervalKey], pairs: list[VisitKey], now: float) -> Held:
        """What the city's mirror holds of a load's keys (nothing without a mirror)."""
        with self._mirror_lock:
            m = self._mirrors.get(city)
            if m is None:
                return Held.nothing(len(ks), len(pairs))
            tasks_rev, n_tasks = m.held_tasks()
            return Held(
                m,
                m.rev,
                m.version,
                tasks_rev,
                n_tasks,
                m.tasks,
                [m.count(k, now) for k in ks],
                [m.visit(k, taxi, now) for k, taxi in pairs],
            )

    def _remember(
        self,
        city: str,
        held: Held,
        read: _Read,
        counts: tuple[list[IntervalKey], list[CountEntry]],
        sets: tuple[list[VisitKey], list[VisitEntry]],
        tasks: dict[TaskId, Task],
    ) -> None:
        """Keep what a load read: merged into the mirror when read at its revision, or as a new mirror when
        the load read every key at a revision newer than the mirror's (an empty revision keeps none)."""
        with self._mirror_lock:
            m = self._mirrors.get(city)
            if not read.rev:
                self._mirrors.pop(city, None)
                return
            if m is None or m.rev != read.rev:
                if held.mirror is not None and read.rev == held.rev:
                    return  # read at the revision the mirror had; a commit of this process moved it on
                if m is not None and m.version >= read.version:
                    self._mirrors.pop(city, None)  # an older read, or the city was reset: start afresh
                    return
                m = self._mirrors[city] = CityMirror(read.rev, read.version)
            fresh = m is not held.mirror  # a new mirror: everything was read
            for k, have, entry in zip(counts[0], held.counts, counts[1], strict=True):
                if fresh or have is None:
                    m.counts[k] = entry
            for kt, have_set, set_entry in zip(sets[0], held.visits, sets[1], strict=True):
                if fresh or have_set is None:
                    m.visits[kt] = set_entry
            if counts[0]:
                m.prune(min(counts[0]))
            if read.tasks_rev:
                m.tasks_rev, m.tasks = read.tasks_rev, tasks
            else:
                m.tasks_rev, m.tasks = "", None

    def _forget(self, city: str) -> None:
        """Drop the city's mirror (a call whose outcome is unknown, a reset)."""
        with self._mirror_lock:
            self._mirrors.pop(city, None)

    def _decode_open(self, city: str, flat: Sequence[str]) -> dict[TaskId, Task]:
        """The open tasks of a load's reply, each JSON text decoded once while it stays the same."""
        cache = self._task_cache.get(city, {})
        out: dict[TaskId, Task] = {}
        seen: dict[str, Task] = {}
        for raw in flat[1::2]:
            t = cache.get(raw)
            if t is None:
                t = task_from_json(raw)
            seen[raw] = t
            out[t.id] = t
        self._task_cache[city] = seen
        return out

    def commit_epoch(self, city: str, commit: EpochCommit) -> CommitResult:
        """Run the commit script (see ``app.ports.Store.commit_epoch``); a commit made on the revisions the
        city's mirror holds is applied to the mirror, any other outcome but a refusal drops it."""
        tag = self._key(city)
        keys = [
            f"{tag}:meta",
            self._key(city, "epoch", commit.epoch_id),
            f"{tag}:intervals",
            f"{tag}:tasks",
            self._key(city, "demand", commit.demand_day or "none"),
            f"{tag}:tasks:done",
            f"{tag}:tasks:done_at",
            f"{tag}:tasks:rev",
        ]
        index: dict[str, int] = {}

        def key_index(key: str) -> int:
            if key not in index:
                keys.append(key)
                index[key] = len(keys)  # Lua arrays are 1-based
            return index[key]

        sets: dict[tuple[IntervalKey, TaxiId], dict[str, None]] = {}  # each visit set's distinct new cells
        for v in commit.visits:
            sets.setdefault((v.interval, v.taxi_id), {})[str(int(v.cell))] = None
        visits = [
            [
                key_index(_count_key(tag, k)),
                key_index(_visit_key(tag, k, taxi)),
                str(int(k)),
                list(cells),
            ]
            for (k, taxi), cells in sets.items()
        ]
        with self._mirror_lock:
            base = self._mirrors.get(city)
            base_rev, base_tasks_rev = ("", "") if base is None else (base.rev, base.held_tasks()[0])
        new_rev = uuid.uuid4().hex
        doc: dict[str, Any] = {
            "epoch_id": commit.epoch_id,
            "hash": commit.body_hash,
            "time": format_time(commit.time_s),
            "expected_version": str(int(commit.expected_version)),
            "ttl": str(int(commit.retention_s)),
            "nonce": commit.nonce,
            "base_rev": base_rev,
            "base_tasks_rev": base_tasks_rev,
            "new_rev": new_rev,
            "visits": visits,
            "done_before": format_time(commit.time_s - commit.retention_s),
            "tasks": [
                [str(t.id), task_to_json(t), "1" if t.status in DONE else "0"] for t in commit.task_updates
            ],
        }
        sent = time.monotonic()
        try:
            with self._guard("committing an epoch"):
                arg = orjson.dumps(doc).decode()
                demand = commit.demand_json if commit.demand_json is not None else ""
                reply = cast(list[Any], self._eval("commit", keys, [arg, commit.response_json, demand]))
        except BaseException:
            self._forget(city)  # applied or not: unknown
            raise
        status = reply[0]
        if status == "committed":
            self._committed(city, commit, (base, base_rev, base_tasks_rev, new_rev), reply, sent)
            return CommitResult("committed", new_version=int(reply[1]))
        if status == "duplicate":
            stored = StoredEpoch(commit.epoch_id, reply[1], float(reply[2]), reply[3])
            return CommitResult("duplicate", stored=stored)
        if status in ("version_mismatch", "stale"):
            return CommitResult(status)
        raise RuntimeError(f"unexpected reply from the commit script: {reply!r}")

    def _committed(
        self,
        city: str,
        commit: EpochCommit,
        revs: tuple[CityMirror | None, str, str, str],
        reply: Sequence[Any],
        sent: float,
    ) -> None:
        """Apply a commit the script reports made on the mirror's revision (``revs``: the mirror it was
        computed with, its revisions, the commit's new revision) to that mirror; else drop the mirror."""
        base, base_rev, base_tasks_rev, new_rev = revs
        with self._mirror_lock:
            m = self._mirrors.get(city)
            if m is None or m is not base or m.rev != base_rev or len(reply) < 4 or reply[2] != "1":
                self._mirrors.pop(city, None)
                return
            m.apply_visits(commit.visits, sent, sent + commit.retention_s - EXPIRY_MARGIN_S)
            m.rev, m.version = new_rev, int(reply[1])
            if not commit.task_updates:
                return
            if reply[3] == "1" and m.held_tasks()[0] == base_tasks_rev:
                m.apply_tasks(commit.task_updates)
                m.tasks_rev = new_rev
            else:
                m.tasks_rev, m.tasks = "", None

    def rewind_epochs(self, city: str, time_s: float) -> RewindResult:
        """Set the last epoch time back (one script on the meta hash)."""
        with self._guard("rewinding the epoch stream"):
            reply = cast(list[Any], self._eval("rewind", [self._key(city, "meta")], [format_time(time_s)]))
        previous = None if len(reply) < 3 else float(reply[2])
        return RewindResult(reply[0], previous, int(reply[1]))

    def reset_epochs(self, city: str) -> int:
        """Delete every key of the city but its fleet records, solve requests and locks (SCAN, then DEL
        in batches: not atomic, so stop posting the city's epochs first)."""
        keep = (self._key(city, "fleet") + ":", self._key(city, "lock") + ":")
        self._forget(city)
        with self._guard("resetting the epoch stream"):
            pattern = _glob_escape(self._key(city)) + ":*"
            doomed = [k for k in self._client.scan_iter(match=pattern, count=1000) if not k.startswith(keep)]
            for i in range(0, len(doomed), 500):
                self._client.delete(*doomed[i : i + 500])
        return len(doomed)

    def put_tasks(self, city: str, tasks: Sequence[Task]) -> PutTasksResult:
        """Register tasks, idempotent per id (finished ones included); on any conflict nothing is written
        (WATCH/MULTI, retried)."""
        key = self._key(city, "tasks")
        done = self._key(city, "tasks", "done")
        rev_key = self._key(city, "tasks", "rev")
        ids = list(dict.fromkeys(str(t.id) for t in tasks))
        if not ids:
            return PutTasksResult()
        with self._guard("registering tasks"), self._client.pipeline(transaction=True) as pipe:
            while True:
                try:
                    pipe.watch(key, done, rev_key)
                    raw = cast(list[str | None], pipe.hmget(key, ids))
                    old = cast(list[str | None], pipe.hmget(done, ids))
                    base_rev = cast(str | None, pipe.get(rev_key)) or ""
                    raw = [r if r is not None else o for r, o in zip(raw, old, strict=True)]
                    existing = {TaskId(i): task_from_json(r) for i, r in zip(ids, raw, strict=True) if r}
                    outcome = classify_tasks(existing.get, tasks)
                    if not outcome.to_write:
                        pipe.unwatch()
                        return outcome.result
                    new_rev = uuid.uuid4().hex  # other stores' mirrors read the open tasks again
                    pipe.multi()
                    pipe.hset(key, mapping={str(i): task_to_json(t) for i, t in outcome.to_write.items()})
                    pipe.set(rev_key, new_rev)
                    pipe.execute()
                    self._registered(city, base_rev, new_rev, list(outcome.to_write.values()))
                    return outcome.result
                except WatchError:
                    continue  # a commit or another registration changed the tasks: compare again

    def _registered(self, city: str, base_rev: str, new_rev: str, written: list[Task]) -> None:
        """Add the tasks a registration wrote to the city's mirror when it held the open tasks at the
        revision the registration replaced (the transaction watched it: nothing else changed the tasks in
        between); else the mirror's tasks are read again at the next load."""
        with self._mirror_lock:
            m = self._mirrors.get(city)
            if m is None or m.tasks is None:
                return
            if base_rev and m.tasks_rev == base_rev:
                m.apply_tasks(written)
                m.tasks_rev = new_rev
            else:
                m.tasks_rev, m.tasks = "", None

    def list_tasks(self, city: str) -> list[Task]:
        """The city's open tasks and its finished ones still within the retention, by id."""
        with self._guard("listing tasks"):
            pipe = self._client.pipeline(transaction=True)
            pipe.hgetall(self._key(city, "tasks", "done"))
            pipe.hgetall(self._key(city, "tasks"))
            done, open_ = pipe.execute()
        return _decode_tasks({**done, **open_})

    def interval_counts(self, city: str, interval: IntervalKey) -> dict[int, int]:
        """Lambda by cell for one interval (cells with zero count absent)."""
        with self._guard("reading counts"):
            raw = cast(dict[str, str], self._client.hgetall(_count_key(self._key(city), interval)))
        return _int_fields(raw)

    def list_intervals(self, city: str) -> list[IntervalKey]:
        """Intervals with at least one count, ascending (intervals whose counts expired are left out)."""
        with self._guard("listing intervals"):
            members = cast(list[str], self._client.zrange(self._key(city, "intervals"), 0, -1))
            ks = [IntervalKey(int(m)) for m in members]
            if not ks:
                return []
            pipe = self._client.pipeline(transaction=False)
            tag = self._key(city)
            for k in ks:
                pipe.exists(_count_key(tag, k))
            alive = pipe.execute()
        return [k for k, n in zip(ks, alive, strict=True) if n]

    def recorded_demand(self, city: str, day: str) -> list[str]:
        """Demand recorded on one local day (``YYYYMMDD``), in commit order."""
        with self._guard("reading recorded demand"):
            return cast(list[str], self._client.lrange(self._key(city, "demand", day), 0, -1))

    def recorded_epochs(self, city: str, days: Sequence[str]) -> list[int]:
        """The length of each day's list (one round trip)."""
        if not days:
            return []
        with self._guard("reading recorded demand"):
            pipe = self._client.pipeline(transaction=False)
            for day in days:
                pipe.llen(self._key(city, "demand", day))
            return [int(n) for n in pipe.execute()]

    # -- fleet sizing ---------------------------------------------------------------------------------

    def publish_recommendation(self, city: str, record: FleetRecord, history_limit: int) -> PublishResult:
        """Compare-and-set the current recommendation and push it on the bounded history (one script)."""
        check_fleet_record(record, "published", history_limit)
        keys = [self._key(city, "fleet", "current"), self._key(city, "fleet", "history")]
        args = [str(record.version), fleet_record_to_json(record), str(int(history_limit))]
        with self._guard("publishing a recommendation"):
            reply = cast(list[Any], self._eval("publish", keys, args))
        if reply[0] == "published":
            return PublishResult("published", int(reply[1]))
        return PublishResult("version_mismatch", int(reply[1]))

    def record_solve_failure(self, city: str, record: FleetRecord, history_limit: int) -> None:
        """Push a failed record on the bounded history (MULTI/EXEC)."""
        check_fleet_record(record, "failed", history_limit)
        key = self._key(city, "fleet", "history")
        with self._guard("recording a failed solve"):
            pipe = self._client.pipeline(transaction=True)
            pipe.lpush(key, fleet_record_to_json(record))
            pipe.ltrim(key, 0, int(history_limit) - 1)
            pipe.execute()

    def current_recommendation(self, city: str) -> FleetRecord | None:
        """The last published recommendation, if any."""
        with self._guard("reading the recommendation"):
            raw = cast(str | None, self._client.hget(self._key(city, "fleet", "current"), "record"))
        return None if raw is None else fleet_record_from_json(raw)

    def recommendation_history(self, city: str, limit: int) -> list[FleetRecord]:
        """Up to ``limit`` history entries, newest first."""
        if limit < 1:
            return []
        with self._guard("reading the recommendation history"):
            raw = cast(list[str], self._client.lrange(self._key(city, "fleet", "history"), 0, limit - 1))
        return [fleet_record_from_json(r) for r in raw]

    def acquire_lock(self, city: str, name: str, ttl_s: float) -> str | None:
        """``SET key token NX PX ttl``: a fresh token, or ``None`` while someone holds the lock."""
        if not ttl_s > 0:
            raise ValueError(f"ttl_s must be positive, got {ttl_s}")
        token = new_lock_token()
        ttl_ms = max(1, round(ttl_s * 1000))
        with self._guard("taking a lock"):
            ok = self._client.set(self._key(city, "lock", name), token, nx=True, px=ttl_ms)
        return token if ok else None

    def release_lock(self, city: str, name: str, token: str) -> bool:
        """Delete the lock only if ``token`` still holds it (compare-and-delete script)."""
        with self._guard("releasing a lock"):
            return bool(self._eval("release", [self._key(city, "lock", name)], [token]))

    def enqueue_solve_request(self, city: str, request: SolveRequest) -> EnqueueResult:
        """Queue the request unless one is pending (one script)."""
        key = self._key(city, "fleet", "requests")
        with self._guard("queueing a solve request"):
            reply = cast(list[Any], self._eval("enqueue", [key], [solve_request_to_json(request)]))
        return EnqueueResult(solve_request_from_json(reply[1]), bool(int(reply[0])))

    def claim_solve_request(self, city: str) -> SolveRequest | None:
        """``LPOP`` the pending request, if any."""
        with self._guard("claiming a solve request"):
            raw = cast(str | None, self._client.lpop(self._key(city, "fleet", "requests")))
        return None if raw is None else solve_request_from_json(raw)

    def pending_solve_request(self, city: str) -> SolveRequest | None:
        """``LINDEX 0`` of the queue: the pending request, left queued."""
        with self._guard("reading the solve queue"):
            raw = cast(str | None, self._client.lindex(self._key(city, "fleet", "requests"), 0))
        return None if raw is None else solve_request_from_json(raw)

    def record_worker_beat(self, city: str, beat: WorkerBeat, keep_s: float) -> None:
        """One script: the beat into the city's hash of workers, older workers' beats pruned, both keys
        living ``keep_s`` from now."""
        if not keep_s > 0:
            raise ValueError(f"keep_s must be positive, got {keep_s}")
        keys = [self._key(city, "fleet", "workers"), self._key(city, "fleet", "workers", "seen")]
        args = [
            beat.worker_id,
            worker_beat_to_json(beat),
            format_time(beat.seen_at_s),
            format_time(beat.seen_at_s - keep_s),
            str(max(1, round(keep_s * 1000))),
        ]
        with self._guard("recording a worker heartbeat"):
            self._eval("beat", keys, args)

    def worker_beats(self, city: str) -> list[WorkerBeat]:
        """The kept beats, newest first."""
        with self._guard("reading worker heartbeats"):
            raw = cast(dict[str, str], self._client.hgetall(self._key(city, "fleet", "workers")))
        beats = [worker_beat_from_json(v) for v in raw.values()]
        return sorted(beats, key=lambda b: (-b.seen_at_s, b.worker_id))

    def close(self) -> None:
        """Release the connections."""
        with self._connect_lock:
            if self._conn is not None:
                self._conn.close()


def _count_key(tag: str, interval: IntervalKey) -> str:
    """The hash of the counts of ``interval`` under the city's key ``tag`` (``RedisStore._key(city)``)."""
    return f"{tag}:count:{int(interval)}"


def _visit_key(tag: str, interval: IntervalKey, taxi: TaxiId) -> str:
    """The set of cells ``taxi`` is counted in during ``interval``, under the city's key ``tag``."""
    return f"{tag}:visit:{int(interval)}:{taxi}"


def _glob_escape(text: str) -> str:
    """``text`` with the glob metacharacters of SCAN MATCH escaped."""
    return "".join("\\" + ch if ch in "*?[]\\" else ch for ch in text)


def _pairs(flat: Sequence[str]) -> dict[str, str]:
    """A hash read inside a script (HGETALL's flat field, value list) as a dict."""
    return dict(zip(flat[::2], flat[1::2], strict=True))


def _int_fields(raw: dict[str, str]) -> dict[int, int]:
    return {int(cell): int(n) for cell, n in raw.items() if int(n) != 0}


class _Read:
    """A load script's reply: the revisions and version it read at monotonic time ``at``, and [value, PTTL]
    per key it read, in the order asked (the count hashes, then the visit sets)."""

    def __init__(self, rev: str, tasks_rev: str, version: int, at: float, rows: Sequence[Any]) -> None:
        self.rev, self.tasks_rev, self.version, self.at = rev, tasks_rev, version, at
        self._rows = iter(rows)

    def entries(
        self, held: Sequence[_E | None], keys: Sequence[_K], entry: Callable[[_K, float, Any], _E]
    ) -> list[_E]:
        """Each key's entry: the mirror's where it holds one, else the next row read."""
        rows, at = self._rows, self.at
        return [
            entry(key, at, next(rows)) if have is None else have for have, key in zip(held, keys, strict=True)
        ]


def _count_entry(_: IntervalKey, at: float, row: Sequence[Any]) -> CountEntry:
    return deadline_of(at, int(row[1])), _int_fields(_pairs(row[0]))


def _visit_entry(key: VisitKey, at: float, row: Sequence[Any]) -> VisitEntry:
    k = key[0]
    cells = frozenset((k, int(c)) for c in row[0].split(",")) if row[0] else frozenset()
    return deadline_of(at, int(row[1])), cells


def _decode_tasks(raw: dict[str, str]) -> list[Task]:
    return [task_from_json(raw[i]) for i in sorted(raw)]
