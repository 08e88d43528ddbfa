"""The twin's HTTP service (FastAPI on uvicorn): ingest, queries, the dashboard.

Every ``/v1`` request carries a token (``Authorization: Bearer ...``): a bus's write token
for that bus's ``POST``/``PUT``, a fleet's read token for that fleet's ``GET``. No token or an
unknown one: 401; a token of another bus or fleet: 403; in both cases nothing is stored.
The OpenAPI schema is at ``/openapi.json`` (and ``/docs``).
"""

from __future__ import annotations

import asyncio
import json
import tempfile
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field

from ebus_env.errors import ConfigError, EbusError
from ebus_env.twin import ingest as payload
from ebus_env.twin.fleet_twin import Twin
from ebus_env.twin.tokens import Grant, Tokens

STATIC = Path(__file__).parent / "static"
SMALL_BODY = 16_384
"""A body up to this size [bytes] (a minute of samples) is checked in the event loop."""
bearer = HTTPBearer(auto_error=False)


class Sample(BaseModel):
    """One 1 Hz sample: the canonical log columns (docs/inputs.md), SI-suffixed names."""

    model_config = ConfigDict(extra="forbid")
    t: float | str = Field(description="UTC time: epoch seconds or ISO 8601")
    speed_kmh: float = Field(ge=0, le=400)
    soc_pct: float | None = Field(None, ge=0, le=100)
    ambient_degc: float | None = Field(None, ge=-50, le=60)
    charging: int | None = Field(None, ge=0, le=1)
    charger_kw: float | None = Field(None, ge=0, le=1000)
    door_open: int | None = Field(None, ge=0, le=1)
    passengers: float | None = Field(None, ge=0, le=300)
    grade_pct: float | None = Field(None, ge=-30, le=30)
    altitude_m: float | None = Field(None, ge=-500, le=6000)
    battery_current_a: float | None = Field(None, ge=-5000, le=5000)
    battery_voltage_v: float | None = Field(None, gt=0, le=2000)
    logged_load_kw: float | None = Field(None, ge=-1000, le=1000)


class BatchIn(BaseModel):
    """A batch of samples; ``batch_id`` makes a re-sent batch a duplicate (else the samples'
    hash does)."""

    model_config = ConfigDict(extra="forbid")
    batch_id: str | None = Field(None, max_length=128)
    samples: list[Sample] = Field(max_length=payload.MAX_ROWS)


BATCH_BODY = {"requestBody": {"required": True, "content": {
    "application/json": {"schema": BatchIn.model_json_schema()},
    "text/csv": {"schema": {"type": "string", "example":
                            "t,speed_kmh,soc_pct\n1746424800,0.0,91.3\n1746424801,1.2,91.3\n"}}}}}
FILE_BODY = {"requestBody": {"required": True, "content": {"application/octet-stream": {
    "schema": {"type": "string", "format": "binary"}}}}}


async def grant(request: Request,
                creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> Grant:
    """The request's token's grant; 401 without a valid one. A cached token costs no
    database query (and no thread)."""
    tokens = request.app.state.tokens
    token = creds.credentials if creds else None
    known, found = tokens.cached(token)
    if not known:
        found = await run_in_threadpool(tokens.grant, token)
    if found is None:
        raise HTTPException(401, "no valid token: send 'Authorization: Bearer <token>' "
                            "(ebus twin token create)", headers={"WWW-Authenticate": "Bearer"})
    return found


Auth = Annotated[Grant, Depends(grant)]


def create_app(twin: Twin, *, mqtt=None, jobs=None) -> FastAPI:
    """The ASGI app of ``twin``; ``jobs`` (re-fits, diagnoses, predictions) and ``mqtt`` (a
    subscriber) start and stop with it."""
    tokens = Tokens(twin.store)

    @asynccontextmanager
    async def lifespan(_app):
        for part in (jobs, mqtt):
            if part is not None:
                part.start()
        yield
        for part in (mqtt, jobs):
            if part is not None:
                part.stop()
        twin.close()

    app = FastAPI(title="ebus twin", version="1",
                  description="The live digital twin of an electric-bus fleet (docs/twin.md)",
                  lifespan=lifespan)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    app.state.tokens = tokens

    def may_write(g: Grant, bus: str) -> None:
        if g.kind != "write" or g.bus != bus:
            raise HTTPException(403, f"this token may not write bus '{bus}'")

    def may_read_fleet(g: Grant, fleet: str) -> None:
        if g.kind != "read" or g.fleet != fleet:
            raise HTTPException(403, f"this token may not read fleet '{fleet}'")

    def may_read_bus(g: Grant, bus: str) -> None:
        fleet = tokens.fleet_of(bus)
        if fleet is None:
            raise HTTPException(404, f"unknown bus '{bus}'")
        may_read_fleet(g, fleet)

    @app.exception_handler(payload.PayloadError)
    async def refused(_request, exc: payload.PayloadError):
        return JSONResponse(exc.to_json(), status_code=exc.status)

    @app.exception_handler(EbusError)
    async def user_error(_request, exc: EbusError):
        return JSONResponse({"error": str(exc)}, status_code=400)

    async def body_of(request: Request, limit: int) -> bytes:
        declared = request.headers.get("content-length")
        if declared and int(declared) > limit:
            raise payload.PayloadError(f"the body is {int(declared)} bytes; at most {limit}",
                                       "body", status=413)
        chunks, size = [], 0
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise payload.PayloadError(f"the body is over {limit} bytes", "body",
                                           status=413)
            chunks.append(chunk)
        return b"".join(chunks)

    async def store(bus: str, batch: payload.Batch):
        """Hand the batch to the twin's writer and wait (without a thread) for the commit of
        its group."""
        return await asyncio.wrap_future(twin.submit(bus, batch))

    @app.get("/healthz", tags=["service"])
    def healthz():
        """Up, and what its writer and jobs have done (none: an ingest-only process)."""
        return {"ok": True, "time": time.time(),
                "writer": {"commits": twin.writer.groups, "batches": twin.writer.batches},
                "jobs": None if jobs is None else jobs.status()}

    @app.post("/v1/buses/{bus}/samples", tags=["ingest"], openapi_extra=BATCH_BODY)
    async def post_samples(bus: str, request: Request, response: Response, g: Auth,
                           batch_id: str | None = None):
        """A batch of 1 Hz samples, as JSON (``BatchIn``) or CSV lines with a header. The
        answer comes once the batch is durable; it says what the batch was (stored,
        duplicate; in order, out of order, late). Its ``Server-Timing`` header gives the
        time from the body's arrival to the commit [ms] (W3C Server Timing)."""
        may_write(g, bus)
        t0 = time.perf_counter()
        body = await body_of(request, payload.MAX_BATCH_BYTES)
        kind = request.headers.get("content-type", "application/json").split(";")[0].strip()
        if kind not in ("text/csv", "application/json", ""):
            raise payload.PayloadError(f"content type '{kind}': send application/json or "
                                       "text/csv", "content-type", status=415)

        # a 10-s batch is checked here at once; an hour's backlog in a thread, so that the
        # event loop keeps answering the others
        if len(body) < SMALL_BODY:
            columns, given = payload.parse_body(body, kind, time.time())
        else:
            columns, given = await run_in_threadpool(payload.parse_body, body, kind, time.time())
        batch_id = batch_id or given or request.headers.get("x-batch-id")
        receipt = await store(bus, payload.batch(columns, batch_id))
        response.headers["Server-Timing"] = f"commit;dur={1e3 * (time.perf_counter() - t0):.1f}"
        return receipt.to_json()

    @app.post("/v1/buses/{bus}/files", tags=["ingest"], openapi_extra=FILE_BODY)
    async def post_file(bus: str, request: Request, g: Auth, name: str = "log.csv"):
        """A logger file (``?name=`` gives its name and so its format: .csv, .csv.gz,
        .parquet, and the CAN formats the project's log reader knows), stored as one
        batch."""
        may_write(g, bus)
        body = await body_of(request, payload.MAX_FILE_BYTES)
        suffix = "".join(Path(name).suffixes[-2:]) or ".csv"

        def read():
            with tempfile.TemporaryDirectory() as folder:
                path = Path(folder) / f"upload{suffix}"
                path.write_bytes(body)
                try:
                    return payload.from_log_file(path)
                except payload.PayloadError:
                    raise
                except EbusError as exc:
                    raise payload.PayloadError(str(exc).replace(str(path), name), "file") \
                        from None

        frame = await run_in_threadpool(read)
        receipt = await store(bus, payload.batch(frame, None))
        return receipt.to_json()

    @app.put("/v1/buses/{bus}/schedules/{day}", tags=["ingest"])
    async def put_schedule(bus: str, day: str, request: Request, g: Auth):
        """The bus's block for ``day`` (YYYY-MM-DD), in the block format of the timetable
        studies (docs/twin.md): its trips and the chargers at their terminals."""
        from ebus_env.twin.schedule import read_block

        may_write(g, bus)
        body = await body_of(request, payload.MAX_BATCH_BYTES)
        try:
            data = json.loads(body)
            block = read_block(data, day)
        except (ValueError, EbusError) as exc:
            raise payload.PayloadError(str(exc), "block") from None
        await run_in_threadpool(twin.store.put_schedule, bus, day, data)
        return {"bus": bus, "day": day, "block": block.block.block_id,
                "trips": len(block.trips), "chargers": len(block.charger_stops)}

    @app.get("/v1/fleets/{fleet}/buses", tags=["query"])
    def get_fleet(fleet: str, g: Auth):
        """Each bus: last seen, SoC now, live or stale, its block's predicted end, alarms."""
        may_read_fleet(g, fleet)
        return {"fleet": fleet, "now": twin.clock(), "buses": twin.fleet(fleet)}

    @app.get("/v1/buses/{bus}", tags=["query"])
    def get_bus(bus: str, g: Auth):
        """The bus page's data: measured SoC, the prediction, fits, diagnoses, alarms."""
        may_read_bus(g, bus)
        return twin.bus(bus)

    @app.get("/v1/buses/{bus}/prediction", tags=["query"])
    def get_prediction(bus: str, g: Auth, band: bool = True):
        """The SoC at each planned charger and at the block's end, predicted now."""
        may_read_bus(g, bus)
        try:
            return twin.predict(bus, band=band).to_json()
        except ConfigError as exc:
            raise HTTPException(409, str(exc)) from None

    @app.get("/v1/fleets/{fleet}/energy-tomorrow", tags=["query"])
    def get_energy(fleet: str, g: Auth):
        """The energy each bus needs for its next block [kWh], from its fitted model."""
        from ebus_env.twin.forecast import energy_tomorrow

        may_read_fleet(g, fleet)
        return {"fleet": fleet, "buses": [energy_tomorrow(twin, b)
                                          for b in twin.store.bus_names(fleet)]}

    @app.get("/", include_in_schema=False)
    def fleet_page():
        return FileResponse(STATIC / "fleet.html")

    @app.get("/bus/{bus}", include_in_schema=False)
    def bus_page(bus: str):
        return FileResponse(STATIC / "bus.html")

    return app
