"""Fault injection for the tests: a TCP proxy that loses one reply, and a redis-server with AOF that can be
killed and started again on the same port and directory. Everything runs on 127.0.0.1 and stops itself."""

from __future__ import annotations

import os
import selectors
import shutil
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import redis

from tests.e2e.service import stop

__all__ = ["LoseReplyProxy", "AofRedis", "free_port", "sigkill"]


def sigkill(proc: subprocess.Popen[bytes] | None) -> int:
    """SIGKILL ``proc`` if it runs and reap it; 1 if it was killed, else 0."""
    if proc is None or proc.poll() is not None:
        return 0
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    return 1


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class LoseReplyProxy:
    """Forwards TCP between clients and ``target``; when armed, the first client packet containing
    ``trigger`` is forwarded to the server, and the connection is cut before the server's reply reaches the
    client (the command ran; its reply is lost). ``cut`` counts such cuts."""

    def __init__(self, target_port: int, trigger: bytes) -> None:
        self.target_port = target_port
        self.trigger = trigger
        self.armed = False
        self.cut = 0
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="lose-reply-proxy", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        self._listener.settimeout(0.2)
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            server = socket.create_connection(("127.0.0.1", self.target_port))
            threading.Thread(target=self._pump, args=(client, server), daemon=True).start()

    def _pump(self, client: socket.socket, server: socket.socket) -> None:
        sel = selectors.DefaultSelector()
        sel.register(client, selectors.EVENT_READ, server)
        sel.register(server, selectors.EVENT_READ, client)
        cutting = False
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(timeout=0.2):
                    src: socket.socket = key.fileobj  # type: ignore[assignment]
                    dst: socket.socket = key.data
                    data = src.recv(65536)
                    if not data:
                        return
                    if src is client and self.armed and self.trigger in data:
                        self.armed = False
                        cutting = True
                        server.sendall(data)
                        time.sleep(0.3)  # let the server run it
                        self.cut += 1
                        return
                    dst.sendall(data)
        except OSError:
            return
        finally:
            if cutting:
                client.shutdown(socket.SHUT_RDWR)
            client.close()
            server.close()
            sel.close()

    def close(self) -> None:
        self._stop.set()
        self._listener.close()
        self._thread.join(timeout=5)


class AofRedis:
    """A redis-server with ``appendonly yes`` on a fixed port and directory: ``kill()`` (SIGKILL, no
    shutdown save) and ``start()`` again, and the AOF brings the data back."""

    def __init__(self, workdir: Path, port: int | None = None) -> None:
        binary = shutil.which("redis-server")
        if binary is None:
            raise RuntimeError("redis-server is not on PATH")
        self.binary = binary
        self.workdir = workdir
        self.port = port or free_port()
        self.url = f"redis://127.0.0.1:{self.port}/0"
        self.proc: subprocess.Popen[bytes] | None = None
        self.kills = 0

    def start(self, timeout_s: float = 15.0) -> None:
        cmd = [self.binary, "--port", str(self.port), "--bind", "127.0.0.1", "--dir", str(self.workdir),
               "--appendonly", "yes", "--appendfsync", "everysec", "--save", "",
               "--logfile", str(self.workdir / "redis.log")]  # fmt: skip
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout_s
        while True:
            client = redis.Redis.from_url(self.url, socket_timeout=1, socket_connect_timeout=1)
            try:
                if client.ping():
                    return
            except redis.RedisError:
                pass
            finally:
                client.close()
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise RuntimeError(f"redis-server on port {self.port} did not start")
            time.sleep(0.05)

    def kill(self) -> None:
        """SIGKILL: no shutdown, no final save; what the AOF holds is what comes back."""
        self.kills += sigkill(self.proc)

    def freeze(self) -> None:
        """SIGSTOP: the server holds its connections and answers nothing."""
        assert self.proc is not None
        os.kill(self.proc.pid, signal.SIGSTOP)

    def thaw(self) -> None:
        assert self.proc is not None
        os.kill(self.proc.pid, signal.SIGCONT)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.thaw()
            stop(self.proc)
