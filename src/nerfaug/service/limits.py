"""How much one request may carry to `nerfaug serve` (images, pixels, bytes; the ranges of what it
asks are its schema's, `nerfaug.capture.requests`), and the body limit that holds for streamed
(chunked) bodies too.

A request's body is counted as it arrives: one over its limit is answered 413 at once, whether or
not it said its length, and nothing more of it is read.
"""

from __future__ import annotations

import json

MEGABYTE = 1024 * 1024
# Images one request may carry (a batch of captures, or a new session's images).
MAX_CAPTURES_PER_REQUEST = 64
# Pixels of one image (its header is read first: a larger one is never decoded); so also of a
# session's camera made from uploads, whose images must have its size.
MAX_IMAGE_PIXELS = 40_000_000
# A JSON body (10,000 poses as JSON take about 3.5 MB).
MAX_JSON_BYTES = 8 * MEGABYTE


def multipart_limit(max_upload_bytes: int) -> int:
    """The largest multipart body: `MAX_CAPTURES_PER_REQUEST` images at the upload limit, plus 1 MB of form."""
    return max_upload_bytes * MAX_CAPTURES_PER_REQUEST + MEGABYTE


class _TooLarge(Exception):
    """Raised into the app's body parsing once the 413 is sent: it stops reading the body."""


class BodyLimit:
    """ASGI middleware: 413 for a body over its limit (multipart: `multipart_limit`, any other:
    `MAX_JSON_BYTES`), from its Content-Length when given, else counted as it streams in: the
    413 is sent the moment the count passes the limit, and what the app makes of the aborted
    body afterwards is dropped."""

    def __init__(self, app, max_upload_bytes: int):
        self.app = app
        self.multipart = multipart_limit(max_upload_bytes)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or [])
        multipart = headers.get(b"content-type", b"").startswith(b"multipart/")
        limit = self.multipart if multipart else MAX_JSON_BYTES
        length = headers.get(b"content-length", b"")
        if length.isdigit() and int(length) > limit:
            return await _answer_413(send, _message(int(length), limit))
        seen, answered, started = 0, False, False

        async def counted():
            nonlocal seen, answered
            message = await receive()
            if message["type"] == "http.request" and not answered:
                seen += len(message.get("body", b""))
                if seen > limit:
                    answered = True
                    if not started:
                        await _answer_413(send, _message(seen, limit, streamed=True))
                    raise _TooLarge
            return message

        async def sending(message):
            nonlocal started
            if answered:
                return  # the app's answer to the body it could not finish: the 413 was sent
            started = True
            await send(message)

        try:
            await self.app(scope, counted, sending)
        except Exception:
            if not answered:
                raise


def _message(size: int, limit: int, streamed: bool = False) -> str:
    if streamed:
        return f"request body: over the limit of {limit / MEGABYTE:.3g} MB (counted as it arrived)"
    return f"request body: {size / MEGABYTE:.1f} MB is over the limit of {limit / MEGABYTE:.3g} MB"


async def _answer_413(send, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": 413, "headers": headers})
    await send({"type": "http.response.body", "body": body})
