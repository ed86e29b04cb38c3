"""The live view's front door: a TCP relay between the viewers and the Foxglove SDK's WebSocket
server, which listens on a loopback port of its own. It exists for three things the SDK's
server (foxglove-sdk 0.30) does not do:

- **Both names of the protocol.** The SDK's server accepts only the subprotocol
  `foxglove.sdk.v1`; Foxglove Studio 1.x and Lichtblick ask for `foxglove.websocket.v1`, the
  same protocol under its first name (the SDK renamed it). The relay passes the upgrade
  request on asking for `foxglove.sdk.v1` and names in the answer the protocol the client
  asked for; after the handshake it copies bytes both ways, unchanged.
- **A handshake timeout.** A client has `HANDSHAKE_S` to send its whole upgrade request (at
  most `HEAD_MAX` bytes); one that sends half of it and then nothing is closed, not waited
  for.
- **A stop with a deadline.** `stop` closes every connection at once (the SDK's server then
  sees its clients gone, and its own stop returns), and a client that takes no data for
  `SLOW_S` is dropped (until then the SDK's per-client backlog drops its oldest messages).

It runs an asyncio loop in a daemon thread; nothing of it runs on the simulation's thread.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import threading

SDK_PROTOCOL = "foxglove.sdk.v1"           # what the SDK's server accepts
OLD_PROTOCOL = "foxglove.websocket.v1"     # Foxglove Studio 1.x, Lichtblick
HANDSHAKE_S = 5.0          # a client's whole upgrade request within this, or it is closed
SLOW_S = 10.0              # a client taking no data for this long is dropped
HEAD_MAX = 16384           # bytes of an upgrade request (and of the server's answer)
CHUNK = 1 << 18            # bytes copied at a time
_PROTO = b"sec-websocket-protocol:"


def _protocols(line: bytes) -> list[str]:
    return [p.strip() for p in line[len(_PROTO):].decode("latin-1").split(",") if p.strip()]


def rename_request(head: bytes) -> tuple[bytes, str | None]:
    """The upgrade request as the SDK takes it, and the name to answer with (None: unchanged):
    a client offering `foxglove.websocket.v1` but not `foxglove.sdk.v1` is asked for as one
    offering `foxglove.sdk.v1`."""
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(_PROTO):
            offered = _protocols(line)
            if SDK_PROTOCOL not in offered and OLD_PROTOCOL in offered:
                lines[i] = b"Sec-WebSocket-Protocol: " + SDK_PROTOCOL.encode()
                return b"\r\n".join(lines), OLD_PROTOCOL
    return head, None


def rename_answer(head: bytes, asked: str | None) -> bytes:
    """The SDK's answer naming the protocol the client asked for."""
    if asked is None:
        return head
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(_PROTO) and _protocols(line) == [SDK_PROTOCOL]:
            lines[i] = b"Sec-WebSocket-Protocol: " + asked.encode()
    return b"\r\n".join(lines)


class Relay:
    """Listens on `host:port` (0: a free port; `port` says which) and relays each client to
    the server at `upstream` (host, port)."""

    def __init__(self, host: str, port: int, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.loop = asyncio.new_event_loop()
        self._tasks: set[asyncio.Task] = set()
        self._writers: set[asyncio.StreamWriter] = set()
        self._server: asyncio.base_events.Server | None = None
        ready: concurrent.futures.Future[int] = concurrent.futures.Future()
        self.thread = threading.Thread(target=self._run, args=(host, port, ready),
                                       name="cosim-live-relay", daemon=True)
        self.thread.start()
        self.port = ready.result()          # OSError when it cannot listen there

    @property
    def clients(self) -> int:
        """Connections open now (before or after their handshake)."""
        return len(self._tasks)

    def _run(self, host: str, port: int, ready: concurrent.futures.Future) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self._server = self.loop.run_until_complete(asyncio.start_server(
                self._serve, host, port, limit=HEAD_MAX))
        except BaseException as exc:   # noqa: BLE001 (handed to the starting thread)
            ready.set_exception(exc)
            self.loop.close()
            return
        ready.set_result(self._server.sockets[0].getsockname()[1])
        self.loop.run_forever()
        self.loop.close()

    def stop(self, timeout: float) -> bool:
        """Close the listener and every connection, stop the loop; False if that took more
        than `timeout` s (the thread is a daemon: it never holds the process)."""
        if not self.thread.is_alive():
            return True
        with contextlib.suppress(RuntimeError):     # the loop already closed
            asyncio.run_coroutine_threadsafe(self._shutdown(), self.loop)
        self.thread.join(timeout)
        return not self.thread.is_alive()

    async def _shutdown(self) -> None:
        if self._server is not None:
            self._server.close()
        for w in list(self._writers):
            w.transport.abort()
        for t in list(self._tasks):
            t.cancel()
        if self._tasks:
            await asyncio.wait(list(self._tasks), timeout=1.0)
        self.loop.stop()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        self._tasks.add(task)
        self._writers.add(writer)
        up_w = None
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
            head, asked = rename_request(head)
            up_r, up_w = await asyncio.wait_for(asyncio.open_connection(
                *self.upstream, limit=CHUNK), HANDSHAKE_S)
            self._writers.add(up_w)
            up_w.write(head)
            answer = await asyncio.wait_for(up_r.readuntil(b"\r\n\r\n"), HANDSHAKE_S)
            writer.write(rename_answer(answer, asked))
            await asyncio.wait_for(writer.drain(), SLOW_S)
            pipes = [asyncio.ensure_future(self._pipe(reader, up_w)),
                     asyncio.ensure_future(self._pipe(up_r, writer))]
            try:
                await asyncio.wait(pipes, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for p in pipes:
                    p.cancel()
        except (TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                asyncio.CancelledError, OSError):
            pass          # a client too slow, gone, or too long-winded: closed below
        finally:
            for w in (writer, up_w):
                if w is not None:
                    w.transport.abort()
                    self._writers.discard(w)
            self._tasks.discard(task)

    @staticmethod
    async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        with contextlib.suppress(TimeoutError, OSError):
            while data := await src.read(CHUNK):
                dst.write(data)
                await asyncio.wait_for(dst.drain(), SLOW_S)
