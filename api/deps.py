"""What the routes share: the app's context and their route class (JSON bodies parsed in a
worker thread)."""

import json
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from typing import Annotated, Any

from anyio import to_thread
from fastapi import Depends, Request, Response
from fastapi.routing import APIRoute
from starlette.exceptions import HTTPException

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


NOT_JSON = "the request body is not valid JSON"


def parse_json(body: bytes) -> Any:
    """``body`` as JSON; HTTPException 400 for bytes that are not JSON text of sane depth and
    numbers (a malformed document raises JSONDecodeError, which is answered 400 the same way:
    ``api.errors``). A body that parses but fails its model is a 422."""
    try:
        return json.loads(body)
    except json.JSONDecodeError:
        raise
    except UnicodeDecodeError:
        raise HTTPException(400, f"{NOT_JSON}: not UTF-8 text") from None
    except RecursionError:
        raise HTTPException(400, f"{NOT_JSON}: it nests too deeply") from None
    except ValueError as exc:  # e.g. an integer of more digits than Python converts
        raise HTTPException(400, f"{NOT_JSON}: {exc}") from None


class _ThreadedJSONRequest(Request):
    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            self._json = await to_thread.run_sync(parse_json, await self.body())
        return self._json


class ThreadedBodyRoute(APIRoute):
    """A route whose JSON body is parsed in a worker thread, so a large body does not hold up
    the event loop (the model's validation after it is bounded by the models' list limits)."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route(request: Request) -> Response:
            return await handler(_ThreadedJSONRequest(request.scope, request.receive))

        return route
