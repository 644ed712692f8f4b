"""Connection-level limits of the studio's HTTP server: a deadline for a request's header lines.

uvicorn closes idle keep-alive connections and the application bounds the time a body may take
(:data:`brdfcodec.studio.server.BODY_TIMEOUT_S`), but nothing bounds the time a client takes to send a request's
header lines: a client sending one header line a second holds a connection (and a file descriptor) for as
long as it likes. :func:`server_config` serves the application with uvicorn's own HTTP protocol, extended so
that the header block of every request must be complete within :data:`HEADER_TIMEOUT_S` of its first byte;
otherwise the server answers ``408 Request Timeout`` and closes the connection.
"""

from __future__ import annotations

import asyncio
from typing import Any

__all__ = ["HEADER_TIMEOUT_S", "header_deadline_protocol", "server_config"]

#: Longest a request's header lines may take to arrive, seconds (from the request's first byte).
HEADER_TIMEOUT_S = 10.0
_END_OF_HEADERS = b"\r\n\r\n"
_TIMEOUT_BODY = b"the request headers did not arrive in time"
_TIMEOUT_RESPONSE = (b"HTTP/1.1 408 Request Timeout\r\nContent-Type: text/plain\r\nConnection: close\r\n"
                     b"Content-Length: %d\r\n\r\n%s" % (len(_TIMEOUT_BODY), _TIMEOUT_BODY))


def header_deadline_protocol(base: type[asyncio.Protocol], timeout: float) -> type[asyncio.Protocol]:
    """A subclass of a uvicorn HTTP protocol class that times out slow header blocks.

    Parameters
    ----------
    base : type
        uvicorn's protocol class (h11 or httptools implementation: anything with ``connection_made``,
        ``data_received``, ``connection_lost`` and ``on_response_complete``).
    timeout : float
        Seconds (> 0) from a request's first byte to the end of its header block (a blank line).

    Returns
    -------
    type
        The protocol class to give ``uvicorn.Config(http=...)``.
    """
    if not timeout > 0:
        raise ValueError(f"header timeout must be positive, got {timeout!r}")

    class HeaderDeadlineProtocol(base):  # type: ignore[valid-type, misc]
        _deadline: asyncio.TimerHandle | None
        _tail: bytes
        _awaiting_headers: bool

        def connection_made(self, transport: Any) -> None:
            super().connection_made(transport)
            self._deadline, self._tail, self._awaiting_headers = None, b"", True
            self._arm()  # a client that connects and sends nothing is timed out too

        def _arm(self) -> None:
            self._disarm()
            self._deadline = asyncio.get_running_loop().call_later(timeout, self._headers_too_slow)

        def _disarm(self) -> None:
            if self._deadline is not None:
                self._deadline.cancel()
                self._deadline = None

        def _headers_too_slow(self) -> None:
            self._deadline = None
            transport = getattr(self, "transport", None)
            if transport is not None and not transport.is_closing():
                transport.write(_TIMEOUT_RESPONSE)
                transport.close()

        def data_received(self, data: bytes) -> None:
            if self._awaiting_headers:
                if self._deadline is None:  # the first byte of the next request on a kept-alive connection
                    self._arm()
                seen = self._tail + data
                if _END_OF_HEADERS in seen:
                    self._awaiting_headers, self._tail = False, b""
                    self._disarm()
                else:
                    self._tail = seen[-(len(_END_OF_HEADERS) - 1):]
            super().data_received(data)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._awaiting_headers, self._tail = True, b""  # the next bytes start a new request

        def connection_lost(self, exc: Exception | None) -> None:
            self._disarm()
            super().connection_lost(exc)

    HeaderDeadlineProtocol.__name__ = HeaderDeadlineProtocol.__qualname__ = f"HeaderDeadline{base.__name__}"
    return HeaderDeadlineProtocol


def server_config(app: Any, *, host: str, port: int, header_timeout: float = HEADER_TIMEOUT_S,
                  **options: Any) -> Any:
    """A ``uvicorn.Config`` for the studio: quiet logs, and :func:`header_deadline_protocol` over uvicorn's
    own choice of HTTP implementation.

    Parameters
    ----------
    app : ASGI application
    host : str
        Address to bind.
    port : int
        Port (0: any free one).
    header_timeout : float, default HEADER_TIMEOUT_S
        Seconds a request's header block may take.
    **options
        Further ``uvicorn.Config`` options.

    Returns
    -------
    uvicorn.Config
    """
    import uvicorn
    from uvicorn.config import HTTP_PROTOCOLS
    from uvicorn.importer import import_from_string

    base = import_from_string(HTTP_PROTOCOLS["auto"])
    options.setdefault("log_level", "warning")
    options.setdefault("access_log", False)
    return uvicorn.Config(app, host=host, port=port, http=header_deadline_protocol(base, header_timeout),
                          **options)
