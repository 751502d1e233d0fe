"""How much one request may ask of `nerfaug serve` (the numbers the request models state, so they
show in the API docs), and the body limit that holds for streamed (chunked) bodies too.

A request's body is counted as it arrives: one over its limit is answered 413 at once, whether or
not it said its length, and nothing more of it is read.
"""

from __future__ import annotations

MEGABYTE = 1024 * 1024
# Images one request may carry (a batch of captures, or a new session's images).
MAX_CAPTURES_PER_REQUEST = 64
# Pixels of one image (its header is read first: a larger one is never decoded); also bounds a
# session's camera made from uploads.
MAX_IMAGE_PIXELS = 40_000_000
# Poses a client may send as candidates (a robot's reachable set) in one proposal.
MAX_REACHABLE_POSES = 10_000
# Hemisphere candidates one proposal may score.
MAX_CANDIDATES = 20_000
# Views one proposal may ask for.
MAX_VIEWS = 1000
# Keep-out cones of one proposal.
MAX_KEEP_OUT = 64
# A JSON body (10,000 poses as JSON take about 3.5 MB).
MAX_JSON_BYTES = 8 * MEGABYTE
# The selection settings whose value sets the work of a proposal, and their largest values.
SELECTION_BOUNDS = {
    "entropy_resolution": 256,
    "fisher_resolution": 256,
    "fisher_train_pixels": 65_536,
    "fisher_train_chunk": 4096,
    "fisher_train_probes": 64,
    "fisher_probes": 64,
    "fisher_cache_floats": 2**28,
    "chunk": 65_536,
    "max_draws": 10_000_000,
}


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
    import json

    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    await send({"type": "http.response.start", "status": 413, "headers": headers})
    await send({"type": "http.response.body", "body": body})
