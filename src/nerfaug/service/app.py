"""The HTTP API over a `SessionHub`: FastAPI routes, thin over the library (the same
`CaptureSession` calls the CLI makes), the token check, the upload limits, and every error as
`{"detail": "one line"}` (`nerfaug.service.errors`).

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

import functools
import hmac
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, File, Form, Request, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError
from starlette.exceptions import HTTPException
from swagger_ui_bundle import swagger_ui_path

import nerfaug
from nerfaug.service import models
from nerfaug.service.errors import ServiceError, bad_input, status_of
from nerfaug.service.hub import SessionHub, check_session_id
from nerfaug.service.uploads import MEGABYTE, check_names, check_poses, parse_json_field, read_upload, write_uploads

# A request may carry this many images of the upload limit (plus the form's other fields).
MAX_IMAGES_PER_REQUEST = 64
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


def answers(endpoint):
    """Turn a library error raised by `endpoint` into its HTTP status (one place: `status_of`)."""

    @functools.wraps(endpoint)
    def wrapper(*args, **kwargs):
        try:
            return endpoint(*args, **kwargs)
        except ServiceError:
            raise
        except ValidationError as error:
            raise bad_input(validation_line(error.errors())) from None
        except Exception as error:  # noqa: BLE001 -- mapped to a status, never a traceback to the client
            raise ServiceError(*status_of(error)) from None

    return wrapper


def _token_ok(request: Request, token: str) -> bool:
    given = request.headers.get("authorization", "")
    return hmac.compare_digest(given.encode(), f"Bearer {token}".encode())


def create_app(hub: SessionHub, token: str | None = None, max_upload_mb: float = 25.0) -> FastAPI:
    """The service's app over `hub`.

    Args:
        hub: the sessions.
        token: when given, every request must send `Authorization: Bearer TOKEN`.
        max_upload_mb: the largest image file accepted (a request may hold
            `MAX_IMAGES_PER_REQUEST` of them).
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
        length = request.headers.get("content-length", "")
        if length.isdigit() and int(length) > limit * MAX_IMAGES_PER_REQUEST + MEGABYTE:
            size, most = int(length) / MEGABYTE, limit * MAX_IMAGES_PER_REQUEST / MEGABYTE
            return JSONResponse({"detail": f"request body: {size:.1f} MB is over the limit of {most:g} MB"}, 413)
        return await call_next(request)

    @app.exception_handler(ServiceError)
    async def service_error(request, error: ServiceError):
        return JSONResponse({"detail": error.message}, error.status)

    @app.exception_handler(RequestValidationError)
    async def invalid(request, error: RequestValidationError):
        return JSONResponse({"detail": validation_line(list(error.errors()))}, 422)

    @app.exception_handler(HTTPException)
    async def http_error(request, error: HTTPException):
        return JSONResponse({"detail": " ".join(str(error.detail).split())}, error.status_code)

    @app.get("/health", response_model=models.Health)
    def health():
        return {"status": "ok", "version": nerfaug.__version__, "sessions": hub.ids()}

    @app.get("/sessions", response_model=list[str])
    def sessions():
        return hub.ids()

    @app.post("/sessions/from-dataset", status_code=201, response_model=models.SessionState)
    @answers
    def create_from_dataset(request: models.CreateFromDataset):
        from nerfaug.capture import CaptureSession

        data = hub.dataset_path(request.dataset)
        return hub.created(
            request.id,
            lambda folder: CaptureSession.create(
                data, folder, split=request.split or "train", device=hub.device, **_settings(request)
            ),
        )

    @app.post("/sessions/from-uploads", status_code=201, response_model=models.SessionState)
    @answers
    def create_from_uploads(
        settings: str = Form(description="JSON of CreateFromUploads: id, intrinsics, poses, preset, seed, ..."),
        images: list[UploadFile] = File(description="the images, in the order of the poses"),
    ):
        import torch

        from nerfaug.cameras import Cameras
        from nerfaug.capture import CaptureSession
        from nerfaug.data import EXCHANGE_FORMAT, DatasetSplit, NewFrame, get_format

        request = models.CreateFromUploads.model_validate(parse_json_field(settings, "settings"))
        check_session_id(request.id)
        k = request.intrinsics
        uploads = [read_upload(f, i, limit, (k.width, k.height)) for i, f in enumerate(images)]
        check_names(uploads)
        poses = check_poses(request.poses, "poses", len(uploads))

        cx, cy = k.width / 2 if k.cx is None else k.cx, k.height / 2 if k.cy is None else k.cy
        camera = Cameras(torch.eye(4), k.fx, k.fy or k.fx, cx, cy, k.width, k.height)
        frames = [NewFrame(u.name, u.data, u.suffix, pose.double().tolist()) for u, pose in zip(uploads, poses)]

        def create(folder: Path):
            with hub.staging() as tmp:
                data = DatasetSplit(Path(tmp) / "data", get_format(EXCHANGE_FORMAT))
                data.append(frames, camera)
                return CaptureSession.create(data.root, folder, device=hub.device, **_settings(request))

        return hub.created(request.id, create)

    @app.get("/sessions/{session_id}", response_model=models.SessionState)
    @answers
    def state(session_id: str):
        return hub.state(session_id)

    @app.post("/sessions/{session_id}/captures", status_code=201, response_model=models.Added)
    @answers
    def add_captures(
        session_id: str,
        poses: str = Form(description="JSON list of 4x4 poses, one per image, in upload order"),
        images: list[UploadFile] = File(description="captured images; their file names name the new views"),
    ):
        def add(session):
            k = session.state.intrinsics
            uploads = [read_upload(f, i, limit, (k.width, k.height)) for i, f in enumerate(images)]
            check_names(uploads)
            matrices = check_poses(parse_json_field(poses, "poses"), "poses", len(uploads))
            with hub.staging() as tmp:
                names = session.add_views(write_uploads(Path(tmp), uploads), matrices)
            session.save()  # the captures are on disk now, and in the checkpoint's count
            return {"names": names, "views": len(session.trainer.train_views), "step": session.step}

        check_session_id(session_id)
        return hub.run(session_id, add)

    @app.post("/sessions/{session_id}/train", status_code=202, response_model=models.Job)
    @answers
    def train(session_id: str, request: models.TrainRequest):
        return hub.train(session_id, request.steps)

    @app.post("/sessions/{session_id}/proposals")
    @answers
    def propose(session_id: str, request: models.ProposeRequest):
        """The proposal as a Blender-style transforms JSON (world-frame poses, angles, scores)."""
        candidates = None if request.candidates is None else check_poses(request.candidates, "candidates")
        constraints = None if request.constraints is None else request.constraints.model_dump()

        def choose(session):
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

        return hub.run(session_id, choose)

    @app.post(
        "/sessions/{session_id}/uncertainty",
        responses={200: {"content": {"image/png": {}, "application/octet-stream": {}}}},
        response_class=Response,
    )
    @answers
    def uncertainty(session_id: str, request: models.UncertaintyRequest):
        """PNG: render, depth, ray entropy and FisherRF panels with colour bars; npz: the arrays."""
        from nerfaug.capture.uncertainty_images import figure_bytes, npz_bytes

        pose = check_poses(request.pose, "pose")
        maps = hub.run(
            session_id,
            lambda session: session.uncertainty_maps(pose, request.width, request.fisher, request.fisher_width)[0],
        )
        if request.format == "npz":
            return Response(npz_bytes(maps), media_type="application/octet-stream")
        return Response(figure_bytes(maps), media_type="image/png")

    @app.post("/sessions/{session_id}/evaluate", response_model=models.Evaluation)
    @answers
    def evaluate(session_id: str, request: models.EvaluateRequest):
        """The session's NeRF scored on a held-out split at its training resolution (`nerfaug eval`)."""
        data = hub.dataset_path(request.dataset)

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

        check_session_id(session_id)
        return hub.run(session_id, score)

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
