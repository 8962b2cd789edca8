"""ASGI middleware: bearer-token auth, request body limit, request timeout, request metrics,
CORS with JSON refusals.

Pure ASGI (no ``BaseHTTPMiddleware``), so streaming responses pass through untouched.
"""

import asyncio
import hmac
import json
import time

from starlette.datastructures import Headers, QueryParams
from starlette.exceptions import HTTPException
from starlette.middleware.cors import CORSMiddleware
from starlette.responses import JSONResponse, Response

from api.errors import ApiError, error_body


async def _send_json(send, status: int, body: dict, headers: list | None = None) -> None:
    payload = json.dumps(body).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(payload)).encode()),
                *(headers or []),
            ],
        }
    )
    await send({"type": "http.response.body", "body": payload})


def token_error(token: str, headers: Headers, query: QueryParams) -> ApiError | None:
    """Why a request with these headers and query may not pass a service whose token is
    ``token`` (None: it may). The token comes as ``Authorization: Bearer <token>`` (or
    ``?access_token=<token>``, for an ``<img>`` or ``EventSource`` that cannot set headers):
    missing -> 401, wrong -> 403."""
    challenge = {"WWW-Authenticate": "Bearer"}
    header = headers.get("authorization")
    if header is not None:
        scheme, _, value = header.partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            message = "the Authorization header must be 'Bearer <token>'"
            return ApiError(401, message, "unauthorized", challenge)
        supplied = value.strip()
    else:
        supplied = query.get("access_token")
    if not supplied:
        return ApiError(401, "this service needs a bearer token", "unauthorized", challenge)
    if not hmac.compare_digest(supplied.encode(), token.encode()):
        return ApiError(403, "the bearer token is not valid", "forbidden")
    return None


class BearerAuth:
    """With a token configured, a request under ``prefix`` without the token is answered
    401 (403 with a wrong one) before anything reads its body: the app is not called."""

    def __init__(self, app, settings, prefix: str = "/v1") -> None:
        self.app = app
        self.settings = settings
        self.prefix = prefix

    async def __call__(self, scope, receive, send):
        token = self.settings.token
        if scope["type"] == "http" and token:
            path = scope.get("path", "")
            if path == self.prefix or path.startswith(self.prefix + "/"):
                query = QueryParams(scope.get("query_string", b"").decode("latin-1"))
                error = token_error(token, Headers(scope=scope), query)
                if error is not None:
                    headers = [
                        (k.lower().encode(), v.encode()) for k, v in (error.headers or {}).items()
                    ]
                    body = error_body(error.status, error.message, error.code)
                    return await _send_json(send, error.status, body, headers)
        return await self.app(scope, receive, send)


class JSONCORSMiddleware(CORSMiddleware):
    """Starlette's CORS middleware, with a refused preflight answered in the service's JSON
    error shape instead of plain text."""

    def preflight_response(self, request_headers: Headers) -> Response:
        response = super().preflight_response(request_headers)
        if response.status_code < 400:
            return response
        headers = {
            k: v for k, v in response.headers.items() if k not in ("content-type", "content-length")
        }
        body = error_body(response.status_code, response.body.decode())
        return JSONResponse(body, response.status_code, headers=headers)


class BodyLimit:
    """Refuse request bodies over their limit with 413: at once when Content-Length says so,
    else as soon as the bytes received pass it (the body is not read further). Uploads and
    commits (which may carry meshes and vertices) may send ``max_upload_bytes``; every other
    request ``max_json_bytes``, so a job of hundreds of thousands of poses is refused before
    anything parses it."""

    def __init__(self, app, settings) -> None:
        self.app = app
        self.settings = settings

    def limit(self, method: str, path: str) -> int:
        scene_change = path.startswith("/v1/scenes") and (
            (method == "POST" and (path == "/v1/scenes" or path.endswith("/commits")))
            or method == "PATCH"
        )
        return self.settings.max_upload_bytes if scene_change else self.settings.max_json_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        limit = self.limit(scope.get("method", ""), scope.get("path", ""))
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    return await _send_json(send, 400, error_body(400, "bad Content-Length"))
                if length > limit:
                    message = f"the request body is larger than the limit of {limit} bytes"
                    return await _send_json(send, 413, error_body(413, message, "too_large"))
        received = 0

        async def counted():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise HTTPException(
                        413, f"the request body is larger than the limit of {limit} bytes"
                    )
            return message

        return await self.app(scope, counted, send)


class Timeout:
    """Answer 504 when a request has not started its response within its time: an upload
    (``POST /v1/scenes``: loading and compiling a big scene takes long) ``upload_timeout``,
    anything else ``request_timeout`` (streams start theirs at once, so they are never cut).
    A request whose body has not all arrived by then is the client's delay: 408."""

    def __init__(self, app, settings, uploads: str = "/v1/scenes") -> None:
        self.app = app
        self.settings = settings
        self.uploads = uploads

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        upload = scope.get("method") == "POST" and scope.get("path") == self.uploads
        seconds = self.settings.upload_timeout if upload else self.settings.request_timeout
        started = False
        headers = Headers(scope=scope)
        received = headers.get("content-length", "0") == "0" and "transfer-encoding" not in headers

        async def watched_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request" and not message.get("more_body", False):
                received = True
            return message

        async def watched_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        task = asyncio.ensure_future(self.app(scope, watched_receive, watched_send))
        done, _ = await asyncio.wait({task}, timeout=seconds)
        if task in done or started:
            return await task
        task.cancel()
        try:
            await task
        except (asyncio.CancelledError, Exception):
            pass
        if not started:
            if not received:
                message = f"the request body did not arrive within {seconds:g} s"
                return await _send_json(send, 408, error_body(408, message, "timeout"))
            message = f"the request did not complete within {seconds:g} s"
            await _send_json(send, 504, error_body(504, message, "timeout"))


class RequestMetrics:
    """Count requests by method, route template and status; time to the first byte."""

    def __init__(self, app, metrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        start = time.perf_counter()
        status = 500

        async def timed_send(message):
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                route = _route(scope)
                self.metrics.request_seconds.labels(route).observe(time.perf_counter() - start)
            await send(message)

        try:
            await self.app(scope, receive, timed_send)
        finally:
            self.metrics.requests.labels(scope.get("method", ""), _route(scope), str(status)).inc()


def _route(scope) -> str:
    """The matched route's template with the prefixes of the routers it was included in
    (``/v1/scenes/{scene_id}``): the route FastAPI reports carries only its own path, so the
    prefix is the part of the request path before the stretch the route's pattern matches."""
    route = scope.get("route")
    template = getattr(route, "path", None)
    if not template:
        return "unmatched"
    path, pattern = scope.get("path", ""), getattr(route, "path_regex", None)
    if pattern is not None and not pattern.fullmatch(path):
        for i in range(1, len(path)):
            if path[i] == "/" and pattern.fullmatch(path[i:]):
                return path[:i] + template
    return template
