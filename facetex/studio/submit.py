"""Job submissions of the studio: transfer, persona build, persona upload, puppet.

Each handler makes the job's folder, saves the uploads there under the studio's own names
(:mod:`facetex.studio.uploads`), checks them (one line naming the user's file), and queues the
CLI commands a user would type::

    POST /api/transfer         content, style (files or bundled sample names), method, preset, size
    POST /api/persona          photos (images and/or zip archives), min_photos
    POST /api/personas         a .persona file (ready at once)
    GET  /api/personas         the personas to choose from (built, uploaded, --personas folder)
    POST /api/puppet           driver clip, persona id, mode, size, side_by_side, max_frames
"""

# no `from __future__ import annotations`: FastAPI reads the routes' annotations, whose types are imported
# inside the factory (fastapi is optional), so they must be evaluated where they are written

import shutil
import sys
from pathlib import Path

from ..errors import BadInputError
from .jobs import Step
from .uploads import (IMAGE_SUFFIXES, MAX_PHOTOS, VIDEO_SUFFIXES, check_image, check_persona, photos_from_zip,
                      save_upload, shown_name, suffix_of)

#: expression textures shown on the Persona page (one per photo, the first ones)
TEXTURES = 6


def facetex_command(*args: str) -> list[str]:
    """``python -m facetex ARGS --json``: this interpreter, so the job runs this facetex."""
    return [sys.executable, "-m", "facetex", *args, "--json"]


def personas(config, jobs) -> dict:
    """{id: (shown name, path)} of the personas the pages may choose: built or uploaded in the
    studio (``job-<id>``), and the ``--personas`` folder's files (``dir-<n>``). A request names
    one by its id, a key of this table."""
    out = {}
    for job in sorted(jobs.jobs(state="done"), key=lambda j: j.created):
        if job.kind in ("persona", "persona-upload"):
            out[f"job-{job.id}"] = (job.info.get("name", job.id), job.folder / "persona.persona")
    if config.personas_dir is not None:
        for k, p in enumerate(sorted(config.personas_dir.glob("*.persona"))):
            out[f"dir-{k}"] = (p.stem, p)
    return out


def add_routes(app, config, jobs) -> None:
    from typing import Annotated

    from fastapi import File, Form, UploadFile
    from starlette.concurrency import run_in_threadpool

    from ..transfer.methods import METHODS, PRESETS

    async def image_input(folder: Path, role: str, upload: UploadFile | None, sample: str | None) -> tuple[str, str]:
        """(file name in the job, name shown) of the content or style image: an upload or a
        bundled sample (by its name in the samples table)."""
        if upload is not None and upload.filename:
            suffix = suffix_of(upload.filename, IMAGE_SUFFIXES, "an image")
            dest = folder / f"{role}{suffix}"
            await save_upload(upload, dest, config.max_upload)
            shown = shown_name(upload.filename)
            await run_in_threadpool(check_image, dest, shown)
            return dest.name, shown
        if sample:
            src = config.samples.get(sample)
            if src is None:
                raise BadInputError(f"no bundled sample named {shown_name(sample)!r}")
            dest = folder / f"{role}{src.suffix.lower()}"
            shutil.copyfile(src, dest)
            return dest.name, src.name
        raise BadInputError(f"no {role} image: upload one or pick a sample")

    @app.post("/api/transfer")
    async def transfer(content: Annotated[UploadFile | None, File()] = None,
                       style: Annotated[UploadFile | None, File()] = None,
                       content_sample: Annotated[str | None, Form()] = None,
                       style_sample: Annotated[str | None, Form()] = None,
                       method: Annotated[str, Form()] = "facetex", preset: Annotated[str, Form()] = "preview",
                       size: Annotated[int | None, Form(ge=32, le=4096)] = None):
        if method not in METHODS:
            raise BadInputError(f"unknown method {shown_name(method)!r}: use one of {', '.join(METHODS)}")
        if preset not in PRESETS:
            raise BadInputError(f"unknown preset {shown_name(preset)!r}: use one of {', '.join(PRESETS)}")
        job_id, folder = jobs.new_folder()
        try:
            c, c_shown = await image_input(folder, "content", content, content_sample)
            s, s_shown = await image_input(folder, "style", style, style_sample)
        except BaseException:
            jobs.discard(job_id, folder)
            raise
        args = ["transfer", c, s, "-o", "result.png", "--method", method, "--preset", preset]
        if size is not None:
            args += ["--size", str(size)]
        job = jobs.submit(job_id, folder, "transfer", [Step("transfer", facetex_command(*args))],
                          outputs={"content": c, "style": s, "result.png": "result.png",
                                   "result.png.json": "result.png.json"},
                          info={"content": c_shown, "style": s_shown, "method": method, "preset": preset,
                                "size": size})
        return job.public(jobs.position(job.id))

    @app.post("/api/persona")
    async def persona(photos: Annotated[list[UploadFile], File()],
                      min_photos: Annotated[int, Form(ge=3, le=MAX_PHOTOS)] = 10,
                      name: Annotated[str | None, Form()] = None):
        job_id, folder = jobs.new_folder()
        pdir = folder / "photos"
        pdir.mkdir()
        n = 0
        try:
            for up in photos:
                suffix = suffix_of(up.filename, IMAGE_SUFFIXES + (".zip",), "a photo or a zip archive")
                if suffix == ".zip":
                    archive = folder / "upload.zip"
                    await save_upload(up, archive, config.max_upload)
                    n += await run_in_threadpool(photos_from_zip, archive, pdir, n, config.max_upload)
                    archive.unlink()
                    continue
                if n >= MAX_PHOTOS:
                    raise BadInputError(f"more than {MAX_PHOTOS} photos: give fewer")
                await save_upload(up, pdir / f"photo_{n:03d}{suffix}", config.max_upload)
                n += 1
            if n < min_photos:
                raise BadInputError(f"{n} photo(s) uploaded, fewer than the {min_photos} needed (min_photos): "
                                    "give more photos of the person")
        except BaseException:
            jobs.discard(job_id, folder)
            raise
        names = sorted(p.name for p in pdir.iterdir())
        refs = names[:: max(1, len(names) // TEXTURES)][:TEXTURES]  # spread over the collection
        outputs = {"persona.persona": "persona.persona", "persona.persona.json": "persona.persona.json",
                   "average.png": "textures/average.png"}
        for k, ref in enumerate(refs):
            outputs[f"texture_{k}.png"] = f"textures/texture_{k}.png"
            outputs[f"photo_{k}{Path(ref).suffix}"] = f"photos/{ref}"
        steps = [Step("build", facetex_command("persona", "build", "photos", "-o", "persona.persona",
                                               "--min-photos", str(min_photos), "--jobs", "1")),
                 Step("textures", [sys.executable, "-m", "facetex.studio.textures", "persona.persona", "textures",
                                   *(f"photos/{r}" for r in refs)])]
        job = jobs.submit(job_id, folder, "persona", steps, outputs=outputs,
                          info={"name": shown_name(name, "persona") if name else f"persona {job_id[:6]}",
                                "photos": n, "textures": len(refs),
                                "references": [f"photo_{k}{Path(r).suffix}" for k, r in enumerate(refs)]})
        return job.public(jobs.position(job.id))

    @app.post("/api/personas")
    async def upload_persona(persona: Annotated[UploadFile, File()]):
        suffix_of(persona.filename, (".persona",), "a .persona file")
        job_id, folder = jobs.new_folder()
        try:
            await save_upload(persona, folder / "persona.persona", config.max_upload)
            await run_in_threadpool(check_persona, folder / "persona.persona", shown_name(persona.filename))
        except BaseException:
            jobs.discard(job_id, folder)
            raise
        name = Path(shown_name(persona.filename)).stem
        job = jobs.add_done(job_id, folder, "persona-upload", {"persona.persona": "persona.persona"},
                            info={"name": name})
        return job.public()

    @app.get("/api/personas")
    async def list_personas():
        return [{"id": k, "name": name} for k, (name, _) in personas(config, jobs).items()]

    @app.post("/api/puppet")
    async def puppet(driver: Annotated[UploadFile, File()], persona: Annotated[str, Form()],
                     mode: Annotated[str, Form()] = "composite",
                     size: Annotated[int, Form(ge=32, le=1024)] = 320,
                     side_by_side: Annotated[bool, Form()] = False,
                     max_frames: Annotated[int | None, Form(ge=1, le=100_000)] = None):
        if mode not in ("composite", "face"):
            raise BadInputError(f"unknown mode {shown_name(mode)!r}: use composite or face")
        chosen = personas(config, jobs).get(persona)
        if chosen is None:
            raise BadInputError(f"no persona {shown_name(persona)!r}: build or upload one first")
        suffix = suffix_of(driver.filename, VIDEO_SUFFIXES, "a video")
        job_id, folder = jobs.new_folder()
        try:
            await save_upload(driver, folder / f"driver{suffix}", config.max_upload)
        except BaseException:
            jobs.discard(job_id, folder)
            raise
        args = ["puppet", f"driver{suffix}", str(chosen[1]), "-o", "puppet.mp4", "--mode", mode, "--size", str(size)]
        if side_by_side:
            args.append("--side-by-side")
        if max_frames:
            args += ["--max-frames", str(max_frames)]
        job = jobs.submit(job_id, folder, "puppet", [Step("puppet", facetex_command(*args))],
                          uses=[persona[4:]] if persona.startswith("job-") else [],
                          outputs={"puppet.mp4": "puppet.mp4", "puppet.mp4.json": "puppet.mp4.json"},
                          info={"driver": shown_name(driver.filename), "persona": chosen[0], "mode": mode,
                                "size": size})
        return job.public(jobs.position(job.id))
