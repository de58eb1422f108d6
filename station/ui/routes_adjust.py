"""The Adjust page's live stream: Server-Sent Events, one message per live reading.

``GET /api/live/stream?axle=front|rear|all``: ``event: status`` messages (the loop starting,
live, paused by a step, an error with what to do) and unnamed messages with each reading
(station/ui/live_feed.py, ``reading_view``). The page's EventSource reconnects by itself.
"""

from __future__ import annotations

import asyncio
import json

from starlette.requests import Request
from starlette.responses import StreamingResponse
from starlette.routing import Route

from station.ui.live_feed import axle_or_refuse
from station.ui.views import finite

POLL_S = 0.01  # how often a stream looks for a new reading (the loop makes 10-30 a second)


def _event(data: dict, name: str | None = None) -> str:
    return (f"event: {name}\n" if name else "") + f"data: {json.dumps(finite(data), allow_nan=False)}\n\n"


async def stream(request: Request):
    axle = axle_or_refuse(request.query_params.get("axle"))
    feed = request.app.state.screen.feed

    async def events():
        feed.subscribe(axle)
        try:
            seen, said, beat = -1, -1, 0.0
            yield ": the station's live values\n\n"
            while True:
                n_status, status = feed.status
                if n_status != said:
                    said = n_status
                    yield _event(status, "status")
                n, message = feed.latest
                if n != seen and message is not None and message.get("axle") == axle:
                    seen = n
                    yield _event(message)
                beat += POLL_S
                if beat > 15:  # a comment now and then keeps proxies and tablets from closing the stream
                    beat = 0.0
                    yield ": keep-alive\n\n"
                await asyncio.sleep(POLL_S)
        finally:
            feed.unsubscribe()

    return StreamingResponse(events(), media_type="text/event-stream",
                             headers={"cache-control": "no-store", "x-accel-buffering": "no"})


routes = [Route("/api/live/stream", stream)]
