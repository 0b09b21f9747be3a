"""A lost commit reply on a real Redis: the commit script runs, its reply is lost on the way back, redis-py
sends the command again on a new connection. The post must say committed (not replayed), and the metrics
must count it, while the script applied the epoch once."""

from __future__ import annotations

from collections.abc import Iterator
from urllib.parse import urlsplit

import pytest

from app.adapters import RedisStore
from tests.api import payloads
from tests.api.conftest import CITY, MakeClient, auth, fingerprint
from tests.faults import LoseReplyProxy

EPOCHS = f"/v1/cities/{CITY}/epochs"


@pytest.fixture
def proxied_store(redis_url: str, redis_prefix: str) -> Iterator[tuple[RedisStore, LoseReplyProxy]]:
    port = urlsplit(redis_url).port
    assert port is not None
    proxy = LoseReplyProxy(port, trigger=b"EVALSHA")
    store = RedisStore(f"redis://127.0.0.1:{proxy.port}/0", prefix=redis_prefix)
    yield store, proxy
    store.close()
    proxy.close()


def test_commit_whose_reply_was_lost_is_reported_committed(
    make_client: MakeClient, proxied_store: tuple[RedisStore, LoseReplyProxy]
) -> None:
    store, proxy = proxied_store
    client = make_client(store=store)
    assert client.post(EPOCHS, json=payloads.epoch("e1", 0), headers=auth()).status_code == 200
    proxy.armed = True  # the commit script is cached now: the next EVALSHA is the commit itself
    r = client.post(EPOCHS, json=payloads.epoch("e2", 1), headers=auth())
    assert proxy.cut == 1, "the reply was not lost: the test did not exercise anything"
    assert r.status_code == 200, r.text
    assert "Idempotent-Replayed" not in r.headers
    assert fingerprint(store)[0] == 2  # each epoch applied once
    text = client.get("/metrics").text
    assert 'sd_epochs_total{outcome="committed"} 2.0' in text  # the re-sent one is a commit, not a replay
    assert 'sd_epochs_total{outcome="replayed"} 1.0' not in text
