"""Errors as JSON: ``{"error": {"status": 422, "code": "invalid_scene", "message": "..."}}``.

Every failure the service reports has that shape, with a message a person can read; an
unexpected exception is logged with its traceback and answered with a 500 that says only that
something went wrong on the server (never the stack trace).
"""

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import iter_route_contexts
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Mount

from tracer.errors import SceneError, TilerenderError

log = logging.getLogger("tilerender.api")

CODES = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    409: "conflict",
    413: "too_large",
    415: "unsupported_media_type",
    422: "invalid",
    429: "too_many",
    500: "internal",
    503: "unavailable",
    504: "timeout",
}


class ApiError(TilerenderError):
    """An error answered as JSON with ``status``; ``code`` is a short machine-readable word."""

    def __init__(
        self, status: int, message: str, code: str | None = None, headers: dict | None = None
    ) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.code = code or CODES.get(status, "error")
        self.headers = headers


def error_body(status: int, message: str, code: str | None = None, **extra) -> dict:
    return {
        "error": {
            "status": status,
            "code": code or CODES.get(status, "error"),
            "message": message,
            **extra,
        }
    }


def error_response(
    status: int, message: str, code: str | None = None, headers: dict | None = None, **extra
) -> JSONResponse:
    return JSONResponse(error_body(status, message, code, **extra), status, headers=headers)


def not_found(what: str, ident: str) -> ApiError:
    return ApiError(404, f"no {what} {ident!r}", "not_found")


def _validation_message(errors: list[dict]) -> str:
    first = errors[0]
    if first.get("type") == "json_invalid":
        reason = (first.get("ctx") or {}).get("error", "invalid JSON")
        return f"the request body is not valid JSON: {reason}"
    loc = [str(p) for p in first.get("loc", ()) if p not in ("body", "query", "path")]
    where = ".".join(loc) or "request"
    message = str(first.get("msg", "invalid value")).removeprefix("Value error, ")
    if first.get("type") == "extra_forbidden":
        message = "unknown field"
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    return f"{where}: {message}{more}"


def _jsonable(errors: list[dict]) -> list[dict]:
    return [
        {
            "loc": [str(p) for p in e.get("loc", ())],
            "msg": str(e.get("msg", "")),
            "type": e.get("type"),
        }
        for e in errors[:20]
    ]


def allowed_methods(app: FastAPI, path: str) -> list[str]:
    """Every method some route of ``app`` answers at ``path`` (a path has one route per
    method: Starlette's 405 names only the first route's); empty when no route matches."""
    methods: set[str] = set()
    for route in iter_route_contexts(app.routes):  # the routes of the included routers too
        if isinstance(route.original_route, Mount) or not route.methods:
            continue  # a mounted app (the static files) names its own methods
        if route.path_regex.fullmatch(path):
            methods |= route.methods
    return sorted(methods)


def _method_not_allowed(request: Request, detail: str, headers: dict) -> tuple[str, dict]:
    """A 405's message and headers with ``Allow`` naming every method of the path."""
    root = request.scope.get("root_path", "")
    path = request.url.path.removeprefix(root) if root else request.url.path
    named = headers.get("Allow", "")  # a mounted app's own (the static files)
    allowed = allowed_methods(request.app, path) or [
        m.strip() for m in named.split(",") if m.strip()
    ]
    if not allowed:
        return detail, headers
    message = f"{request.method} is not allowed here (allowed: {', '.join(allowed)})"
    return message, {**headers, "Allow": ", ".join(allowed)}


def install(app: FastAPI) -> None:
    """Register the handlers that turn every exception into the JSON error shape."""

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        return error_response(exc.status, exc.message, exc.code, exc.headers)

    @app.exception_handler(SceneError)
    async def _scene_error(request: Request, exc: SceneError) -> JSONResponse:
        return error_response(422, str(exc).splitlines()[0] or "invalid scene", "invalid_scene")

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = list(exc.errors())
        if not errors:
            return error_response(422, "invalid request")
        if errors[0].get("type") == "json_invalid":  # not JSON at all: a syntax error
            return error_response(400, _validation_message(errors), "bad_request")
        return error_response(
            422, _validation_message(errors), "invalid", details=_jsonable(errors)
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else CODES.get(exc.status_code, "error")
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            detail, headers = _method_not_allowed(request, detail, headers or {})
        return error_response(exc.status_code, detail, headers=headers)

    @app.exception_handler(TimeoutError)
    async def _timeout(request: Request, exc: TimeoutError) -> JSONResponse:
        return error_response(504, "the cluster did not answer in time; try again", "timeout")

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error in %s %s", request.method, request.url.path)
        return error_response(500, "internal server error (see the server's log)", "internal")
