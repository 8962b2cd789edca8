"""Dependencies of the routes: the app's context and bearer-token auth."""

import hmac
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from api.errors import ApiError
from api.events import EventHub
from api.metrics import Metrics
from api.scenes import SceneRepository
from api.service import RenderService
from api.settings import Settings
from api.store import Store


@dataclass
class Context:
    """Everything an app holds: built in its lifespan, reached through ``app.state.ctx``."""

    settings: Settings
    store: Store
    scenes: SceneRepository
    service: RenderService
    events: EventHub
    metrics: Metrics


def get_context(request: Request) -> Context:
    ctx = getattr(request.app.state, "ctx", None)
    if ctx is None:  # pragma: no cover - only before the lifespan ran
        raise ApiError(503, "the service is starting", "unavailable")
    return ctx


Ctx = Annotated[Context, Depends(get_context)]

_bearer = HTTPBearer(auto_error=False, description="the service's token, if it has one")


def require_token(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """With a token configured, every /v1 request needs ``Authorization: Bearer <token>``
    (or ``?access_token=<token>``, for an ``<img>`` or ``EventSource`` that cannot set
    headers): missing -> 401, wrong -> 403."""
    token = request.app.state.settings.token
    if not token:
        return
    supplied = None
    header = request.headers.get("authorization")
    if header is not None:
        scheme, _, value = header.partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            raise ApiError(
                401,
                "the Authorization header must be 'Bearer <token>'",
                "unauthorized",
                {"WWW-Authenticate": "Bearer"},
            )
        supplied = value.strip()
    else:
        supplied = request.query_params.get("access_token")
    if not supplied:
        raise ApiError(
            401, "this service needs a bearer token", "unauthorized", {"WWW-Authenticate": "Bearer"}
        )
    if not hmac.compare_digest(supplied.encode(), token.encode()):
        raise ApiError(403, "the bearer token is not valid", "forbidden")
