"""The HTTP API over a `SessionHub`: FastAPI routes, thin over the library (the same
`CaptureSession` calls the CLI makes, with the capture core's schemas as request models), the token
check, the body limits (`limits`), a log line per request (`RequestLog`), and every error as
`{"detail": "one line"}` (`nerfaug.service.errors`).

Health and session states are answered on the event loop from snapshots; every other request's
work runs in the hub's bounded per-session queues (`work`), so a busy session never delays them.

    GET  /health                                 liveness, version, session ids
    GET  /sessions                               session ids
    POST /sessions/from-dataset                  a session on a dataset folder inside the root (JSON)
    POST /sessions/from-uploads                  a session from images + poses + intrinsics (multipart)
    GET  /sessions/{id}                          state: views, step, last losses, the training job
    POST /sessions/{id}/captures                 add images + poses (multipart; a batch)
    POST /sessions/{id}/train                    train N steps in the background (poll the state)
    POST /sessions/{id}/proposals                propose N views (method, settings, constraints)
    POST /sessions/{id}/uncertainty              render, depth, entropy and FisherRF images of a pose
    POST /sessions/{id}/evaluate                 PSNR, SSIM, LPIPS on held-out views of a dataset inside the root
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import time
from contextlib import asynccontextmanager
from typing import Annotated

from fastapi import APIRouter, Depends, FastAPI, File, Form, Request, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from swagger_ui_bundle import swagger_ui_path

import nerfaug
from nerfaug.capture.evaluate import trained_on_count
from nerfaug.capture.pool import Job, SessionStatus
from nerfaug.capture.proposal_request import ProposalRequest
from nerfaug.capture.requests import Poses
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.uncertainty_images import figure_bytes, npz_bytes
from nerfaug.errors import NerfaugError
from nerfaug.schema import UNKNOWN_FIELD
from nerfaug.service import models
from nerfaug.service.errors import (
    ServiceError,
    bad_input,
    field_line,
    headers_of,
    meant,
    problems_line,
    public_answer,
    public_text,
)
from nerfaug.service.hub import SessionHub
from nerfaug.service.limits import MAX_CAPTURES_PER_REQUEST, MEGABYTE, BodyLimit
from nerfaug.service.uploads import form_json, read_uploads

# Where the API page's script and style are served from: Swagger UI's files as the package
# `swagger_ui_bundle` ships them, so /docs works on a closed network (FastAPI's own page loads
# them from a CDN).
DOCS_ASSETS = "/docs-assets"
# The library's errors that are answers (a 4xx or a 503, `status_of`); anything else is a 500 (also logged).
ANSWERED = (ServiceError, NerfaugError, ValueError, FileNotFoundError, Exception)
FORMS = ("multipart/form-data", "application/x-www-form-urlencoded")


async def known_fields_only(request: Request) -> None:
    """Refuse a query parameter or form field the route does not take (422 naming it): a field a
    client sends is used or refused, never ignored. A JSON body's fields are its model's (their
    config forbids others)."""
    taken = request.scope["route"].dependant
    sent, known = list(request.query_params), _names(taken, "query_params")
    if request.headers.get("content-type", "").startswith(FORMS):
        sent += list((await request.form()).keys())  # parsed once: FastAPI reads the same form
        known |= _names(taken, "body_params")
    for name in sent:
        if name not in known:
            raise bad_input(field_line(name, UNKNOWN_FIELD + meant(name, sorted(known))))


def _names(dependant, kind: str) -> set[str]:
    """The names of the `kind` parameters ("query_params", "body_params") a route's `dependant`
    takes, its dependencies' too."""
    return {p.alias for p in getattr(dependant, kind)}.union(*(_names(d, kind) for d in dependant.dependencies))


router = APIRouter(dependencies=[Depends(known_fields_only)])


def _answer(request: Request, error: Exception) -> JSONResponse:
    """A library error as its HTTP status and one line (`status_of`)."""
    if isinstance(error, ValidationError):
        return JSONResponse({"detail": problems_line(error.errors())}, 422)
    status, message = public_answer(error, _hub(request).root)  # no server path in an answer
    return JSONResponse({"detail": message}, status, headers=headers_of(error))


def _hub(request: Request) -> SessionHub:
    return request.app.state.hub


def _upload_limit(request: Request) -> int:
    return request.app.state.upload_limit


Hub = Annotated[SessionHub, Depends(_hub)]
UploadLimit = Annotated[int, Depends(_upload_limit)]


async def done(future):
    """The result of work queued in the hub (`SessionHub.submit`), awaited without blocking the loop."""
    return await asyncio.wrap_future(future)


@router.get("/health", response_model=models.Health)
async def health(hub: Hub):
    return {"status": "ok", "version": nerfaug.__version__, "sessions": hub.ids()}


@router.get("/sessions", response_model=list[str])
async def sessions(hub: Hub):
    return hub.ids()


async def created(hub: SessionHub, session_id: str, create) -> dict:
    """Create a session with `create(folder, warn)` in its queue; its state and its warnings."""
    found: list[str] = []

    def warn(line: str, _kind) -> None:
        found.append(line)

    status = await done(hub.submit_create(session_id, lambda folder: create(folder, warn)))
    return {**status.model_dump(), "warnings": found}


@router.post("/sessions/from-dataset", status_code=201, response_model=models.Created)
async def create_from_dataset(request: models.FromDataset, hub: Hub):
    data, request = hub.dataset_path(request.dataset, request.split), hub.settings_of(request)

    def create(folder, warn):
        return CaptureSession.create(data, folder, request, split=request.split, device=hub.device, warn=warn)

    return await created(hub, request.id, create)


@router.post("/sessions/from-uploads", status_code=201, response_model=models.Created)
async def create_from_uploads(
    hub: Hub,
    limit: UploadLimit,
    settings: str = Form(description="JSON of FromUploads: id, intrinsics, poses, engine, seed, ..."),
    images: list[UploadFile] = File(
        description=f"the images, in the order of the poses (at most {MAX_CAPTURES_PER_REQUEST})"
    ),
):
    request = hub.settings_of(form_json(settings, "settings", models.FromUploads))

    def create(folder, warn):
        files = read_uploads(images, limit)
        return CaptureSession.from_files(
            files, request.poses, request.intrinsics, folder, request, device=hub.device, warn=warn
        )

    return await created(hub, request.id, create)


@router.get("/sessions/{session_id}", response_model=SessionStatus)
async def state(session_id: str, hub: Hub):
    """The session's state from its last snapshot: answered at once, even while it trains."""
    if hub.has_snapshot(session_id):
        return hub.state(session_id)
    return await run_in_threadpool(hub.state, session_id)  # reads its files once


@router.post("/sessions/{session_id}/captures", status_code=201, response_model=models.Added)
async def add_captures(
    session_id: str,
    hub: Hub,
    limit: UploadLimit,
    poses: str = Form(description="JSON list of 4x4 poses, one per image, in upload order"),
    images: list[UploadFile] = File(
        description="captured images (PNG, JPEG, TIFF, BMP or WebP; stored under the suffix of the format their "
        f"bytes are); their file names name the new views; at most {MAX_CAPTURES_PER_REQUEST}"
    ),
):
    hub.folder(session_id)
    matrices = form_json(poses, "poses", Poses)

    def add(session):
        names = session.add_files(read_uploads(images, limit), matrices)
        session.save()  # the captures are on disk now, and in the checkpoint's count
        summary = session.summary()
        return models.Added(
            names=names, views=summary.views, step=summary.step, warnings=session.additions[-1].warnings
        )

    return await done(hub.submit(session_id, add))


@router.post("/sessions/{session_id}/train", status_code=202, response_model=Job)
async def train(session_id: str, request: models.TrainRequest, hub: Hub):
    return await done(hub.submit_train(session_id, request.steps))


@router.post("/sessions/{session_id}/proposals")
async def propose(session_id: str, request: ProposalRequest, hub: Hub):
    """The proposal as a Blender-style transforms JSON (world-frame poses, angles, scores)."""

    def choose(session):
        proposal = session.propose(request)
        session.save()
        answer = proposal.transforms()
        answer["nerfaug"]["health"] = session.state.proposals[-1].health  # the check, untrained poses included
        return answer

    return await done(hub.submit(session_id, choose))


@router.post(
    "/sessions/{session_id}/uncertainty",
    responses={200: {"content": {"image/png": {}, "application/octet-stream": {}}}},
    response_class=Response,
)
async def uncertainty(session_id: str, request: models.UncertaintyRequest, hub: Hub):
    """PNG: render, depth, ray entropy and FisherRF panels with colour bars; npz: the arrays."""

    def images(session):
        maps = session.uncertainty_maps([request.pose], request.width, request.fisher, request.fisher_width)[0]
        return npz_bytes(maps) if request.format == "npz" else figure_bytes(maps)

    data = await done(hub.submit(session_id, images))
    return Response(data, media_type="application/octet-stream" if request.format == "npz" else "image/png")


@router.post("/sessions/{session_id}/evaluate", response_model=models.Evaluation)
async def evaluate(session_id: str, request: models.EvaluateRequest, hub: Hub):
    """The session's NeRF scored on a held-out split at its training resolution (`nerfaug eval`)."""
    hub.folder(session_id)
    data = hub.dataset_path(request.dataset, request.split)  # a split named: its listing checked now

    def score(session):
        split = request.split or session.default_test_split()
        hub.dataset_path(request.dataset, split)  # its listing, checked before it is read
        views, chosen = session.test_views(data, split, request.max_views)
        result = session.evaluate(views, lpips="auto" if request.lpips else None)
        root = hub.root.resolve()  # no server path in the answer
        status, scored = public_text(result.lpips_status, root), public_text(chosen.says, root)
        found = {"views": len(views), **result.mean, "lpips_status": status, "per_view": result.per_view}
        found["trained_on"] = trained_on_count(result)
        found["scored"], found["note"] = scored, None if chosen.note is None else public_text(chosen.note, root)
        return {"step": session.step, "dataset": request.dataset, "split": split, **found}

    return await done(hub.submit(session_id, score))


def _token_ok(request: Request, token: str) -> bool:
    given = request.headers.get("authorization", "")
    return hmac.compare_digest(given.encode(), f"Bearer {token}".encode())


def create_app(hub: SessionHub, token: str | None = None, max_upload_mb: float = 25.0) -> FastAPI:
    """The service's app over `hub`.

    Args:
        hub: the sessions.
        token: when given, every request must send `Authorization: Bearer TOKEN`.
        max_upload_mb: the largest image file accepted (a request may hold
            `MAX_CAPTURES_PER_REQUEST` of them).
    """

    @asynccontextmanager
    async def lifespan(app):
        hub.resume()
        yield
        hub.shutdown()

    app = FastAPI(
        title="nerfaug capture service",
        version=nerfaug.__version__,
        description="Active capture over sessions: train, propose reachable views, add captures, uncertainty images.",
        lifespan=lifespan,
        docs_url=None,  # served below, with its assets from the package
        redoc_url=None,  # ReDoc's page would load its script from a CDN
    )
    app.state.hub, app.state.upload_limit = hub, int(max_upload_mb * MEGABYTE)
    app.mount(DOCS_ASSETS, StaticFiles(directory=str(swagger_ui_path)), name="docs-assets")
    app.add_api_route("/docs", _docs_page, include_in_schema=False)
    _guard(app, token)
    app.add_middleware(BodyLimit, max_upload_bytes=app.state.upload_limit)  # before anything reads the body
    app.add_middleware(RequestLog)  # outermost: every answer logged, the refused ones too
    for kind in ANSWERED:
        app.add_exception_handler(kind, _answer)
    app.add_exception_handler(RequestValidationError, _invalid)
    app.add_exception_handler(HTTPException, _http_error)
    app.include_router(router)
    return app


# One line per request (`RequestLog`); `nerfaug serve` prints them on stderr.
log = logging.getLogger(__name__)


class RequestLog:
    """ASGI middleware: one log line per HTTP request when its answer is sent: method, path, status
    and milliseconds, e.g. "POST /sessions/s1/proposals 200 5321 ms" (500 when the app raised)."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start, status = time.perf_counter(), 500

        async def sending(message):
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            elapsed = (time.perf_counter() - start) * 1000
            log.info("%s %s %d %.0f ms", scope["method"], scope["path"], status, elapsed)


def _docs_page(request: Request):
    return get_swagger_ui_html(
        openapi_url=request.app.openapi_url,
        title=f"{request.app.title} - API",
        swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
        swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
        swagger_favicon_url=f"{DOCS_ASSETS}/favicon-32x32.png",
    )


def _guard(app: FastAPI, token: str | None) -> None:
    """Every request sends `Authorization: Bearer TOKEN` when a token is set (401 otherwise)."""

    @app.middleware("http")
    async def guard(request: Request, call_next):
        if token is not None and not _token_ok(request, token):
            return JSONResponse({"detail": "missing or wrong token: send 'Authorization: Bearer TOKEN'"}, 401)
        return await call_next(request)


async def _invalid(request: Request, error: RequestValidationError) -> JSONResponse:
    """Every problem of a request FastAPI refused, in one line naming each field (`problems_line`);
    an unknown field of a JSON body with the field of its model it may have meant."""
    return JSONResponse({"detail": problems_line(list(error.errors()), _body_kind(request))}, 422)


def _body_kind(request: Request):
    """The model of the route's JSON body, as its errors locate fields ("body", field, ...); None
    when it has none, or several (their errors also name the parameter)."""
    route = request.scope.get("route")
    body = getattr(getattr(route, "dependant", None), "body_params", [])
    embedded = getattr(route, "_embed_body_fields", True)
    return body[0].field_info.annotation if len(body) == 1 and not embedded else None


async def _http_error(request: Request, error: HTTPException) -> JSONResponse:
    detail = public_text(" ".join(str(error.detail).split()), _hub(request).root)
    return JSONResponse({"detail": detail}, error.status_code)
