"""The studio's ASGI app (FastAPI): pages, job status and files, errors as one line.

Routes (the job submissions are in :mod:`facetex.studio.submit`, the Live WebSocket in
:mod:`facetex.studio.live`)::

    GET  /  /transfer  /persona  /puppet  /live      the pages (static HTML + JS, no build step)
    GET  /static/...                                 their scripts and styles
    GET  /api/info                                   methods, presets, samples, limits
    GET  /api/samples/{name}                         a bundled sample portrait
    GET  /api/jobs  /api/jobs/{id}                   job states (JSON)
    GET  /api/jobs/{id}/events                       a job's progress (Server-Sent Events)
    GET  /api/jobs/{id}/files/{name}                 one of the job's outputs
    POST /api/jobs/{id}/cancel                       cancel a queued or running job (its folder is removed)

Every error is ``{"error": "<one line>"}`` with a 4xx status (bad input 400, unknown job or file
404, a job that has already finished cannot be cancelled 409, too large 413, queue full 503), the
same line the CLI prints after ``facetex: error:``.
"""

# no `from __future__ import annotations`: FastAPI reads the routes' annotations, whose types are imported
# inside the factory (fastapi is optional), so they must be evaluated where they are written

import asyncio
import contextlib
import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import BadInputError, FacetexError
from .jobs import FINISHED, JobQueue, QueueFullError
from .uploads import BodyLimit, UploadTooLargeError

STATIC = Path(__file__).parent / "static"
PAGES = {"/": "index.html", "/transfer": "transfer.html", "/persona": "persona.html", "/puppet": "puppet.html",
         "/live": "live.html"}


@dataclass
class StudioConfig:
    """The studio's settings (``facetex serve``'s options)."""

    workdir: Path
    max_upload: int  # bytes of one request
    personas_dir: Path | None = None
    samples: dict = field(default_factory=dict)  # {name: path} of the bundled portraits


def _samples() -> dict:
    from .._resources import sample_path

    return {p.name: p for p in sorted(sample_path().glob("*.jpg"))}


def create_app(workdir=None, *, max_upload_mb: float = 200, workers: int = 1, max_queued: int = 8,
               personas_dir=None, job_env: dict | None = None, keep_jobs: int | None = None,
               job_ttl: float | None = None, cleanup_interval: float = 60.0):
    """The studio as an ASGI app (serve it with uvicorn: ``facetex serve`` does).

    Parameters
    ----------
    workdir : str or os.PathLike, optional
        Folder of the job folders (default: a new temporary folder).
    max_upload_mb : float
        Largest request (all its files) in MB; larger uploads get a 413 and one line.
    workers : int
        Jobs run at once (default 1); others wait in order.
    max_queued : int
        Jobs that may wait; beyond, a submission gets a 503 ("queue is full").
    personas_dir : str or os.PathLike, optional
        A folder of ``.persona`` files offered on the Puppet and Live pages besides the
        personas built or uploaded in the studio.
    job_env : dict, optional
        Extra environment variables of the jobs' processes (e.g. ``OMP_NUM_THREADS``).
    keep_jobs : int, optional
        Finished jobs whose folders are kept, the newest (default: all); older ones are removed at
        start-up and every ``cleanup_interval`` seconds, folders an earlier server left included.
    job_ttl : float, optional
        Seconds after which a finished job's folder is removed (default: never).
    cleanup_interval : float
        Seconds between two clean-ups (when ``keep_jobs`` or ``job_ttl`` is set).

    Returns
    -------
    fastapi.FastAPI
        The app; ``app.state.jobs`` is its :class:`~facetex.studio.jobs.JobQueue`.

    Examples
    --------
    >>> import uvicorn
    >>> from facetex.studio import create_app
    >>> uvicorn.run(create_app("studio_jobs"), port=8000)  # doctest: +SKIP
    """
    from fastapi import FastAPI, Request
    from fastapi.exceptions import RequestValidationError
    from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
    from fastapi.staticfiles import StaticFiles
    from starlette.exceptions import HTTPException

    if not max_upload_mb > 0:
        raise BadInputError(f"the upload limit must be positive, not {max_upload_mb} MB")
    workdir = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="facetex-studio-"))
    workdir.mkdir(parents=True, exist_ok=True)
    if keep_jobs is not None and keep_jobs < 0:
        raise BadInputError(f"keep_jobs must be 0 or more, not {keep_jobs}")
    if job_ttl is not None and not job_ttl > 0:
        raise BadInputError(f"the jobs' time to live must be positive, not {job_ttl} s")
    if personas_dir is not None and not Path(personas_dir).is_dir():
        raise BadInputError("not a folder of .persona files", path=personas_dir)
    config = StudioConfig(workdir.resolve(), int(max_upload_mb * 2**20),
                          Path(personas_dir).resolve() if personas_dir else None, _samples())
    jobs = JobQueue(workdir, workers=workers, max_queued=max_queued, env=job_env, keep=keep_jobs, ttl=job_ttl,
                    cleanup_interval=cleanup_interval)

    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        jobs.close()  # a running command is terminated with the server

    app = FastAPI(title="facetex studio", docs_url=None, redoc_url=None, openapi_url=None, lifespan=lifespan)
    app.state.config, app.state.jobs = config, jobs

    def error(status: int, message: str):
        return JSONResponse({"error": message}, status_code=status)

    @app.exception_handler(FacetexError)
    async def facetex_error(request: Request, exc: FacetexError):
        status = 413 if isinstance(exc, UploadTooLargeError) else 503 if isinstance(exc, QueueFullError) else 400
        return error(status, str(exc))

    @app.exception_handler(RequestValidationError)
    async def bad_request(request: Request, exc: RequestValidationError):
        # one line naming the field, like argparse's "argument --size: expected an integer"
        e = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(x) for x in e.get("loc", ())[1:]) or "request"
        return error(400, f"{where}: {e.get('msg', 'invalid')}")

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException):
        return error(exc.status_code, str(exc.detail) if exc.detail else "error")

    def page(name: str):
        async def serve_page():
            return FileResponse(STATIC / name, media_type="text/html")
        return serve_page

    for route, name in PAGES.items():
        app.add_api_route(route, page(name), methods=["GET"], include_in_schema=False)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/api/info")
    async def info():
        from .. import __version__
        from ..transfer.methods import METHODS, PRESETS

        return {"version": __version__, "methods": list(METHODS), "presets": list(PRESETS),
                "samples": list(config.samples), "max_upload_mb": config.max_upload / 2**20}

    @app.get("/api/samples/{name}")
    async def sample(name: str):
        path = config.samples.get(name)  # a key of the table, never a path
        if path is None:
            raise HTTPException(404, f"no bundled sample named {name!r}")
        return FileResponse(path)

    def job_or_404(job_id: str):
        job = jobs.get(job_id)
        if job is None:
            raise HTTPException(404, "no such job")
        return job

    @app.get("/api/jobs")
    async def list_jobs():
        return [j.public(jobs.position(j.id)) for j in sorted(jobs.jobs(), key=lambda j: j.created)]

    @app.get("/api/jobs/{job_id}")
    async def job_state(job_id: str):
        return job_or_404(job_id).public(jobs.position(job_id))

    @app.get("/api/jobs/{job_id}/events")
    async def job_events(job_id: str, request: Request):
        job = job_or_404(job_id)

        async def stream():
            last = None
            while True:
                state = json.dumps(job.public(jobs.position(job_id)))
                if state != last:
                    last = state
                    yield f"data: {state}\n\n"
                if job.state in FINISHED or await request.is_disconnected():
                    return
                await asyncio.sleep(0.2)

        return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})

    @app.post("/api/jobs/{job_id}/cancel")
    async def cancel_job(job_id: str):
        from starlette.concurrency import run_in_threadpool

        job = job_or_404(job_id)
        if job.state in ("done", "failed"):
            raise HTTPException(409, f"job {job_id} has already finished ({job.state})")
        job = await run_in_threadpool(jobs.cancel, job_id)  # waits for a running command's end
        return job.public(jobs.position(job_id))

    @app.get("/api/jobs/{job_id}/files/{name}")
    async def job_file(job_id: str, name: str, download: bool = False):
        job_or_404(job_id)
        path = jobs.file(job_id, name)
        if path is None:
            raise HTTPException(404, f"job {job_id} has no file {name!r}")
        return FileResponse(path, filename=name if download else None)

    from . import live, submit

    submit.add_routes(app, config, jobs)
    live.add_routes(app, config, jobs)
    app.add_middleware(BodyLimit, limit=config.max_upload)
    return app
