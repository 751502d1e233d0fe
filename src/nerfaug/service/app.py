"""The HTTP API over a `SessionHub`: FastAPI routes, thin over the library (the same
`CaptureSession` calls the CLI makes), the token check, the request limits (`limits`), and every
error as `{"detail": "one line"}` (`nerfaug.service.errors`).

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
import functools
import hmac
import inspect
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, File, Form, Request, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from swagger_ui_bundle import swagger_ui_path

import nerfaug
from nerfaug.service import models
from nerfaug.service.errors import ServiceError, bad_input, status_of
from nerfaug.service.hub import SessionHub, check_session_id
from nerfaug.service.limits import MAX_CAPTURES_PER_REQUEST, MEGABYTE, BodyLimit
from nerfaug.service.uploads import check_names, check_poses, parse_json_field, read_upload, write_uploads

# Kept for clients of earlier versions: images one request may carry.
MAX_IMAGES_PER_REQUEST = MAX_CAPTURES_PER_REQUEST
# Where the API page's script and style are served from: Swagger UI's files as the package
# `swagger_ui_bundle` ships them, so /docs works on a closed network (FastAPI's own page loads
# them from a CDN).
DOCS_ASSETS = "/docs-assets"


def validation_line(errors: list[dict]) -> str:
    """Pydantic's errors as one line: the first error's field, message and value."""
    first = errors[0]
    where = ".".join(str(part) for part in first.get("loc", ()) if part not in ("body", "query", "path", "form"))
    text = f"{where or 'request'}: {first.get('msg', 'invalid')}"
    if "input" in first and first.get("type") != "missing":
        text += f" (got {str(first['input'])[:80]!r})"
    if len(errors) > 1:
        text += f" (and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''})"
    return " ".join(text.split())


def _as_service_error(error: Exception) -> ServiceError:
    if isinstance(error, ServiceError):
        return error
    if isinstance(error, ValidationError):
        return bad_input(validation_line(error.errors()))
    return ServiceError(*status_of(error))


def answers(endpoint):
    """Turn a library error raised by `endpoint` (or by the work it awaited) into its HTTP status
    (one place: `status_of`)."""
    if inspect.iscoroutinefunction(endpoint):

        @functools.wraps(endpoint)
        async def waiting(*args, **kwargs):
            try:
                return await endpoint(*args, **kwargs)
            except Exception as error:  # noqa: BLE001 -- mapped to a status, never a traceback to the client
                raise _as_service_error(error) from None

        return waiting

    @functools.wraps(endpoint)
    def wrapper(*args, **kwargs):
        try:
            return endpoint(*args, **kwargs)
        except Exception as error:  # noqa: BLE001 -- mapped to a status, never a traceback to the client
            raise _as_service_error(error) from None

    return wrapper


async def done(future):
    """The result of work queued in the hub (`SessionHub.submit`), awaited without blocking the loop."""
    return await asyncio.wrap_future(future)


def check_count(images: list, field: str = "images") -> None:
    if len(images) > MAX_CAPTURES_PER_REQUEST:
        raise ServiceError(
            413, f"{field}: {len(images)} files; a request may carry at most {MAX_CAPTURES_PER_REQUEST} images"
        )


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
    limit = int(max_upload_mb * MEGABYTE)

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
    app.mount(DOCS_ASSETS, StaticFiles(directory=str(swagger_ui_path)), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs():
        return get_swagger_ui_html(
            openapi_url=app.openapi_url,
            title=f"{app.title} - API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon-32x32.png",
        )

    @app.middleware("http")
    async def guard(request: Request, call_next):
        if token is not None and not _token_ok(request, token):
            return JSONResponse({"detail": "missing or wrong token: send 'Authorization: Bearer TOKEN'"}, 401)
        return await call_next(request)

    app.add_middleware(BodyLimit, max_upload_bytes=limit)  # outermost: before anything reads the body

    @app.exception_handler(ServiceError)
    async def service_error(request, error: ServiceError):
        return JSONResponse({"detail": error.message}, error.status, headers=error.headers)

    @app.exception_handler(RequestValidationError)
    async def invalid(request, error: RequestValidationError):
        return JSONResponse({"detail": validation_line(list(error.errors()))}, 422)

    @app.exception_handler(HTTPException)
    async def http_error(request, error: HTTPException):
        return JSONResponse({"detail": " ".join(str(error.detail).split())}, error.status_code)

    @app.get("/health", response_model=models.Health)
    async def health():
        return {"status": "ok", "version": nerfaug.__version__, "sessions": hub.ids()}

    @app.get("/sessions", response_model=list[str])
    async def sessions():
        return hub.ids()

    @app.post("/sessions/from-dataset", status_code=201, response_model=models.SessionState)
    @answers
    async def create_from_dataset(request: models.CreateFromDataset):
        from nerfaug.capture import CaptureSession

        split = request.split or "train"
        data = hub.dataset_path(request.dataset, split)
        create = functools.partial(CaptureSession.create, data, split=split, device=hub.device, **_settings(request))
        return await done(hub.submit_create(request.id, create))

    @app.post("/sessions/from-uploads", status_code=201, response_model=models.SessionState)
    @answers
    async def create_from_uploads(
        settings: str = Form(description="JSON of CreateFromUploads: id, intrinsics, poses, preset, seed, ..."),
        images: list[UploadFile] = File(
            description=f"the images, in the order of the poses (at most {MAX_CAPTURES_PER_REQUEST})"
        ),
    ):
        request = models.CreateFromUploads.model_validate(parse_json_field(settings, "settings"))
        check_session_id(request.id)
        check_count(images)

        def create(folder: Path):
            import torch

            from nerfaug.cameras import Cameras
            from nerfaug.capture import CaptureSession
            from nerfaug.data import EXCHANGE_FORMAT, DatasetSplit, NewFrame, get_format

            k = request.intrinsics
            uploads = [read_upload(f, i, limit, (k.width, k.height)) for i, f in enumerate(images)]
            check_names(uploads)
            poses = check_poses(request.poses, "poses", len(uploads))
            cx, cy = k.width / 2 if k.cx is None else k.cx, k.height / 2 if k.cy is None else k.cy
            camera = Cameras(torch.eye(4), k.fx, k.fy or k.fx, cx, cy, k.width, k.height)
            frames = [NewFrame(u.name, u.data, u.suffix, pose.double().tolist()) for u, pose in zip(uploads, poses)]
            with hub.staging() as tmp:
                data = DatasetSplit(Path(tmp) / "data", get_format(EXCHANGE_FORMAT))
                data.append(frames, camera)
                return CaptureSession.create(data.root, folder, device=hub.device, **_settings(request))

        return await done(hub.submit_create(request.id, create))

    @app.get("/sessions/{session_id}", response_model=models.SessionState)
    @answers
    async def state(session_id: str):
        """The session's state from its last snapshot: answered at once, even while it trains."""
        if hub.has_snapshot(session_id):
            return hub.state(session_id)
        return await run_in_threadpool(hub.state, session_id)  # reads its session.json once

    @app.post("/sessions/{session_id}/captures", status_code=201, response_model=models.Added)
    @answers
    async def add_captures(
        session_id: str,
        poses: str = Form(description="JSON list of 4x4 poses, one per image, in upload order"),
        images: list[UploadFile] = File(
            description="captured images (PNG, JPEG, TIFF, BMP or WebP; stored under the suffix of the format "
            f"their bytes are); their file names name the new views; at most {MAX_CAPTURES_PER_REQUEST}"
        ),
    ):
        check_session_id(session_id)
        check_count(images)

        def add(session):
            k = session.state.intrinsics
            uploads = [read_upload(f, i, limit, (k.width, k.height)) for i, f in enumerate(images)]
            check_names(uploads)
            matrices = check_poses(parse_json_field(poses, "poses"), "poses", len(uploads))
            with hub.staging() as tmp:
                names = session.add_views(write_uploads(Path(tmp), uploads), matrices)
            session.save()  # the captures are on disk now, and in the checkpoint's count
            warned = session.state.additions[-1].extra.get("warnings", [])
            return {"names": names, "views": len(session.trainer.train_views), "step": session.step, "warnings": warned}

        return await done(hub.submit(session_id, add))

    @app.post("/sessions/{session_id}/train", status_code=202, response_model=models.Job)
    @answers
    async def train(session_id: str, request: models.TrainRequest):
        return await done(hub.submit_train(session_id, request.steps))

    @app.post("/sessions/{session_id}/proposals")
    @answers
    async def propose(session_id: str, request: models.ProposeRequest):
        """The proposal as a Blender-style transforms JSON (world-frame poses, angles, scores)."""
        constraints = None if request.constraints is None else request.constraints.model_dump()

        def choose(session):
            candidates = None if request.candidates is None else check_poses(request.candidates, "candidates")
            proposal = session.propose(
                request.n,
                request.method,
                candidates=candidates,
                n_candidates=request.n_candidates,
                seed=request.seed,
                config=request.selection or None,
                constraints=constraints,
                min_separation=request.min_separation,
            )
            session.save()
            return proposal.transforms()

        return await done(hub.submit(session_id, choose))

    @app.post(
        "/sessions/{session_id}/uncertainty",
        responses={200: {"content": {"image/png": {}, "application/octet-stream": {}}}},
        response_class=Response,
    )
    @answers
    async def uncertainty(session_id: str, request: models.UncertaintyRequest):
        """PNG: render, depth, ray entropy and FisherRF panels with colour bars; npz: the arrays."""
        from nerfaug.capture.uncertainty_images import figure_bytes, npz_bytes

        pose = check_poses(request.pose, "pose")

        def images(session):
            maps = session.uncertainty_maps(pose, request.width, request.fisher, request.fisher_width)[0]
            return npz_bytes(maps) if request.format == "npz" else figure_bytes(maps)

        data = await done(hub.submit(session_id, images))
        return Response(data, media_type="application/octet-stream" if request.format == "npz" else "image/png")

    @app.post("/sessions/{session_id}/evaluate", response_model=models.Evaluation)
    @answers
    async def evaluate(session_id: str, request: models.EvaluateRequest):
        """The session's NeRF scored on a held-out split at its training resolution (`nerfaug eval`)."""
        check_session_id(session_id)
        data = hub.dataset_path(request.dataset, request.split)

        def score(session):
            views = session.held_out(data, request.split, request.max_views)
            result = session.evaluate(views, lpips="auto" if request.lpips else None)
            return {
                "step": session.step,
                "dataset": request.dataset,
                "split": request.split,
                "views": len(views),
                **result.mean,
                "lpips_status": result.lpips_status,
                "per_view": result.per_view,
            }

        return await done(hub.submit(session_id, score))

    return app


def _settings(request: models.SessionSettings) -> dict:
    return {
        "preset": request.preset,
        "seed": request.seed,
        "downscale": request.downscale,
        "centre": request.centre,
        "radius": request.radius,
        "up": request.up,
    }
