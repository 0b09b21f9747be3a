"""The collector kept out of epoch exchanges (``app.api.collector``): off while any held exchange is in
flight, on again when the last one ends, and then the collection its counts are due."""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator

import pytest

from app.api.collector import CollectorDeferral


@pytest.fixture
def collector() -> Iterator[None]:
    """The collector as it was, enabled and with its thresholds, whatever a test does to it."""
    was_enabled, thresholds = gc.isenabled(), gc.get_threshold()
    gc.enable()
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        (gc.enable if was_enabled else gc.disable)()


def test_the_collector_is_off_until_the_last_of_overlapping_exchanges_ends(collector: None) -> None:
    deferral = CollectorDeferral()
    first, second = deferral.held(), deferral.held()
    first.__enter__()
    assert not gc.isenabled()
    second.__enter__()  # another exchange, begun before the first ended
    first.__exit__(None, None, None)
    assert not gc.isenabled()  # the second is still in flight
    second.__exit__(None, None, None)
    assert gc.isenabled()


def test_exchanges_on_threads_share_one_count(collector: None) -> None:
    deferral = CollectorDeferral()
    inside = threading.Barrier(3)
    leave = threading.Event()
    seen: list[bool] = []

    def exchange() -> None:
        with deferral.held():
            inside.wait(timeout=10)
            leave.wait(timeout=10)
            seen.append(gc.isenabled())

    threads = [threading.Thread(target=exchange) for _ in range(2)]
    for t in threads:
        t.start()
    inside.wait(timeout=10)
    assert not gc.isenabled()
    leave.set()
    for t in threads:
        t.join(timeout=10)
    assert seen == [False, False]
    assert gc.isenabled()


def test_an_exchange_leaves_a_collector_turned_off_elsewhere_off(collector: None) -> None:
    gc.disable()
    with CollectorDeferral().held():
        assert not gc.isenabled()
    assert not gc.isenabled()


def test_an_exchange_that_fails_turns_the_collector_on_again(collector: None) -> None:
    with pytest.raises(RuntimeError), CollectorDeferral().held():
        raise RuntimeError("the route failed")
    assert gc.isenabled()


def test_the_collection_owed_is_made_as_the_exchange_ends(collector: None) -> None:
    """Past its threshold inside an exchange, the collector does not run there; it runs at the first
    allocation after the exchange, and the cycles made inside are gone."""
    gc.collect()
    gc.set_threshold(100, 1_000_000, 1_000_000)  # the young generation is due after 100 objects
    runs: list[int] = []

    def seen(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            runs.append(info["generation"])

    class Node:
        def __init__(self) -> None:
            self.me = self

    gc.callbacks.append(seen)
    try:
        with CollectorDeferral().held():
            for _ in range(1_000):
                Node()  # a cycle: only the collector frees it
            assert runs == []
            assert sum(isinstance(o, Node) for o in gc.get_objects(generation=0)) == 1_000
        _ = [None]  # the first allocation after the exchange
        assert runs and runs[0] == 0
    finally:
        gc.callbacks.remove(seen)
    assert not any(isinstance(o, Node) for o in gc.get_objects())
