"""ASGI middleware: request body size limit (413 as problem+json), stalled bodies (408), JSON bodies only (415)."""

from __future__ import annotations

import asyncio
import json

from starlette.exceptions import HTTPException

from starlette.requests import Request

from app.api.problems import PROBLEM_MEDIA_TYPE, problem_type


class BodyTooLarge(HTTPException):
    def __init__(self, limit: int):
        super().__init__(413, f"the request body is larger than the limit of {limit} bytes (NCS_MAX_BODY_BYTES)")


class BodySizeLimit:
    """Rejects bodies over ``limit`` bytes: by Content-Length up front, and by
    counting the streamed chunks (chunked transfer or a lying header)."""

    def __init__(self, app, limit: int):
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    too_big = int(value) > self.limit
                except ValueError:
                    too_big = False
                if too_big:
                    return await self._reject(scope, send)
        received = 0
        limit = self.limit

        async def limited_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(limit)
            return message

        await self.app(scope, limited_receive, send)

    async def _reject(self, scope, send):
        body = json.dumps({
            "type": problem_type(Request(scope), "too-large"), "title": "Content Too Large", "status": 413,
            "detail": f"the request body is larger than the limit of {self.limit} bytes (NCS_MAX_BODY_BYTES)",
            "instance": scope.get("path", ""),
        }).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                                (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})


class BodyStalled(HTTPException):
    def __init__(self, seconds: float):
        super().__init__(408, f"the request body stalled: none of it arrived for {seconds:g} s (NCS_BODY_TIMEOUT); "
                              "send the whole body without pausing", headers={"Connection": "close"})


class BodyTimeout:
    """408 for a request whose body stops arriving for ``seconds`` (a client that sent 9 of 1,000 bytes held its
    connection for ever). Only the pause between two chunks is limited, so a slow body that keeps arriving is
    served; once the body is complete, ``receive`` is passed through untouched (responses that wait for the
    client to disconnect use it)."""

    def __init__(self, app, seconds: float):
        self.app = app
        self.seconds = seconds

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not self.seconds:
            return await self.app(scope, receive, send)
        complete = False
        seconds = self.seconds

        async def timed_receive():
            nonlocal complete
            if complete:
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), seconds)
            except asyncio.TimeoutError:
                complete = True
                raise BodyStalled(seconds) from None
            if message["type"] != "http.request" or not message.get("more_body", False):
                complete = True
            return message

        await self.app(scope, timed_receive, send)


def _is_json(content_type: str) -> bool:
    media = content_type.split(";", 1)[0].strip().lower()
    return media == "application/json" or (media.startswith("application/") and media.endswith("+json"))


class JsonBodiesOnly:
    """415 for a request body that is not JSON (``text/plain``, curl's default form type...) on the
    endpoints that take one, naming Content-Type; otherwise the body would reach validation as bytes
    and get a 422 "Input should be a valid dictionary" that does not say what is wrong."""

    def __init__(self, app, paths: frozenset[str]):
        self.app = app
        self.paths = paths

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and scope["method"] == "POST" and scope["path"] in self.paths:
            for name, value in scope.get("headers", ()):
                if name == b"content-type":
                    content_type = value.decode("latin-1")
                    if not _is_json(content_type):
                        return await self._reject(scope, send, content_type)
                    break
            else:  # no Content-Type at all: FastAPI would not parse the body as JSON either
                return await self._reject(scope, send, None)
        return await self.app(scope, receive, send)

    async def _reject(self, scope, send, content_type: str | None):
        got = "no Content-Type" if content_type is None else repr(content_type.split(";", 1)[0].strip()[:100])
        body = json.dumps({
            "type": problem_type(Request(scope), "unsupported-media-type"), "title": "Unsupported Media Type",
            "status": 415,
            "detail": f"the request body must be JSON: send Content-Type: application/json (got {got})",
            "instance": scope.get("path", ""),
            "errors": [{"loc": ["header", "Content-Type"], "pointer": "", "type": "unsupported_media_type",
                        "msg": "Content-Type must be application/json"}],
        }).encode()
        await send({"type": "http.response.start", "status": 415,
                    "headers": [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                                (b"content-length", str(len(body)).encode()),
                                (b"accept", b"application/json")]})
        await send({"type": "http.response.body", "body": body})
