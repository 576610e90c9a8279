"""The studio's job queue: each job runs facetex commands in child processes, one job at a time.

A job is a list of steps, each a command line (``python -m facetex transfer ...``), run in its
own folder ``WORKDIR/jobs/<id>`` under a random id. The commands are the CLI's own: the outputs,
their JSON sidecars, the atomic writes and the one-line error messages are exactly a user's at the
shell. A child process also keeps a crash, a memory spike or a cancelled job out of the server.

Progress is read from the child's tqdm bar on stderr (``desc: 45%|...| 12/27 [..., stage=flow]``);
a failed step's message is its ``facetex: error: ...`` line, with the job folder's path taken out
(the user never sees the server's paths, only the names inside the job).

Jobs wait in a bounded FIFO: with one worker (the default) two users cannot run two heavy jobs at
once on a small machine, and a full queue refuses a new job instead of growing without bound.

**Cancelling** (:meth:`JobQueue.cancel`): a queued job leaves the queue; a running job's command is
stopped with its whole process group (each step runs in a session of its own: SIGTERM, then SIGKILL
after :data:`KILL_GRACE` s), and no later step starts. Either way the job ends "cancelled" and its
folder (inputs and partial outputs) is removed.

**Cleaning up** (:meth:`JobQueue.cleanup`): the folders of finished jobs (done, failed, cancelled),
and job folders left by an earlier server on the same work folder, are removed when there are more
than ``keep`` of them (the newest are kept) or when they are older than ``ttl`` seconds; at start-up
and then every ``cleanup_interval`` seconds. Only directories directly under ``WORKDIR/jobs`` whose
name is a job id are ever removed (never a symbolic link, never a path outside it); queued and running
jobs, the folders being uploaded to, and the personas used by a queued or running job or by an open
Live session are kept.
"""

from __future__ import annotations

import os
import re
import secrets
import shutil
import signal
import subprocess
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import FacetexError

#: a job id: 16 lowercase hex digits (64 random bits); anything else names no job
JOB_ID = re.compile(r"^[0-9a-f]{16}$")
#: tqdm's bar: "desc:  45%|####      | 12/27 [00:03<00:04, 3.2eval/s, level=1, stage=flow]"
_BAR = re.compile(r"^(?P<desc>[^:|]*):\s*(?P<pct>\d+)%\|[^|]*\|\s*(?P<n>\d+)/(?P<total>\d+)(?P<rest>.*)$")
_STAGE = re.compile(r"stage=([A-Za-z][\w ]*)")
#: seconds a cancelled command has between SIGTERM and SIGKILL
KILL_GRACE = 3.0
#: states of a job that has ended
FINISHED = ("done", "failed", "cancelled")


class QueueFullError(FacetexError):
    """The studio's job queue is full: try again when a job has finished."""

    exit_code = 3


@dataclass
class Step:
    """One command of a job: ``argv`` (run in the job's folder) and the label shown for it."""

    label: str
    argv: list[str]


@dataclass
class Job:
    """A job's state, as the pages see it (:meth:`public`)."""

    id: str
    kind: str
    folder: Path
    steps: list[Step]
    #: files the job may serve: {public name: file name inside the folder}
    outputs: dict = field(default_factory=dict)
    #: what the pages show besides the files (names of inputs, options)
    info: dict = field(default_factory=dict)
    state: str = "queued"  # queued | running | done | failed | cancelled
    step: int = 0
    stage: str = ""
    progress: float = 0.0
    error: str | None = None
    result: dict = field(default_factory=dict)
    created: float = field(default_factory=time.time)
    started: float | None = None
    finished: float | None = None
    #: ids of the jobs whose files this job reads (a puppet job's persona): kept while it runs
    uses: list = field(default_factory=list)
    cancelling: bool = False

    def public(self, position: int | None = None) -> dict:
        """The JSON of the job: no server path, only names inside the job."""
        return {"id": self.id, "kind": self.kind, "state": self.state, "position": position,
                "step": self.step, "steps": [s.label for s in self.steps], "stage": self.stage,
                "progress": round(self.progress, 4), "error": self.error, "info": self.info, "result": self.result,
                "files": sorted(n for n, f in self.outputs.items() if (self.folder / f).is_file()),
                "seconds": None if self.started is None else round((self.finished or time.time()) - self.started, 2)}


class JobQueue:
    """Jobs in their own folders under ``workdir/jobs``, run FIFO by ``workers`` threads.

    Parameters
    ----------
    workdir : str or os.PathLike
        Folder of the job folders (created).
    workers : int
        Jobs run at once (default 1: a heavy job has the machine to itself).
    max_queued : int
        Jobs that may wait; :meth:`submit` raises :class:`QueueFullError` beyond.
    env : dict, optional
        Extra environment of the child processes.
    keep : int, optional
        Finished jobs whose folders are kept (the newest); None: no limit.
    ttl : float, optional
        Seconds after which a finished job's folder is removed; None: no limit.
    cleanup_interval : float
        Seconds between two clean-ups (the first runs at once) when ``keep`` or ``ttl`` is set.
    """

    def __init__(self, workdir, *, workers: int = 1, max_queued: int = 8, env: dict | None = None,
                 keep: int | None = None, ttl: float | None = None, cleanup_interval: float = 60.0):
        self.root = Path(workdir).resolve() / "jobs"
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_queued = max_queued
        self.env = {**os.environ, **(env or {})}
        self.keep, self.ttl = keep, ttl
        self._jobs: dict[str, Job] = {}
        self._waiting: deque[str] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._procs: dict[str, subprocess.Popen] = {}
        self._reserved: set[str] = set()  # folders made for a job not submitted yet (uploads arriving)
        self._pins: dict[str, int] = {}  # job ids whose files are in use outside the queue (a Live session)
        self._threads = [threading.Thread(target=self._work, name=f"facetex-studio-worker-{i}", daemon=True)
                         for i in range(workers)]
        if keep is not None or ttl is not None:
            self.cleanup()  # at start-up: what an earlier server left
            self._threads.append(threading.Thread(target=self._cleaner, args=(max(0.05, cleanup_interval),),
                                                  name="facetex-studio-cleanup", daemon=True))
        for t in self._threads:
            t.start()

    # -- creating and finding jobs --------------------------------------------------------------
    def new_folder(self) -> tuple[str, Path]:
        """A fresh job id and its empty folder (the uploads go there before :meth:`submit`)."""
        while True:
            job_id = secrets.token_hex(8)
            folder = self.root / job_id
            with self._cond:
                try:
                    folder.mkdir()
                except FileExistsError:  # 64 random bits: practically never
                    continue
                self._reserved.add(job_id)
            return job_id, folder

    def add_done(self, job_id: str, folder: Path, kind: str, outputs: dict, info: dict | None = None) -> Job:
        """Record a job that needs no command (an uploaded persona): done at once."""
        job = Job(job_id, kind, folder, [], outputs=dict(outputs), info=info or {}, state="done", progress=1.0)
        job.started = job.finished = time.time()
        with self._cond:
            self._jobs[job_id] = job
            self._reserved.discard(job_id)
        return job

    def submit(self, job_id: str, folder: Path, kind: str, steps: list[Step], outputs: dict,
               info: dict | None = None, uses: list | None = None) -> Job:
        """Queue a job whose inputs are in ``folder``; :class:`QueueFullError` when the queue is full.
        ``uses``: ids of the jobs whose files the job reads (kept by the clean-up while it runs)."""
        job = Job(job_id, kind, folder, steps, outputs=dict(outputs), info=info or {}, uses=list(uses or []))
        with self._cond:
            if len(self._waiting) >= self.max_queued:
                raise QueueFullError(f"the studio's queue is full ({self.max_queued} jobs waiting): "
                                     "try again when a job has finished")
            self._jobs[job_id] = job
            self._reserved.discard(job_id)
            self._waiting.append(job_id)
            self._cond.notify()
        return job

    def discard(self, job_id: str, folder: Path) -> None:
        """Remove the folder of a job that was never submitted (its uploads were refused)."""
        with self._cond:
            self._reserved.discard(job_id)
        self._remove(folder)

    def cancel(self, job_id: str) -> Job | None:
        """Cancel a queued or running job: it ends "cancelled", its command's process group is
        stopped (SIGTERM, then SIGKILL after :data:`KILL_GRACE` s) and its folder is removed. Returns
        the job (unchanged when it had already finished), or None for no such job. Blocks until a
        running command has ended."""
        with self._cond:
            job = self._jobs.get(job_id) if isinstance(job_id, str) and JOB_ID.match(job_id) else None
            if job is None or job.state in FINISHED:
                return job
            job.cancelling = True
            queued = job.state == "queued"
            if queued:
                self._waiting.remove(job_id)
                job.state, job.finished = "cancelled", time.time()
            proc = self._procs.get(job_id)
        if queued:
            self._remove(job.folder)
            return job
        if proc is not None:
            self._kill(proc)
        deadline = time.monotonic() + KILL_GRACE + 10
        while job.state not in FINISHED and time.monotonic() < deadline:  # the worker removes the folder
            time.sleep(0.02)
        return job

    def pin(self, job_id: str) -> None:
        """Keep a job's folder from the clean-up until :meth:`unpin` (a persona open in a Live session)."""
        with self._cond:
            self._pins[job_id] = self._pins.get(job_id, 0) + 1

    def unpin(self, job_id: str) -> None:
        with self._cond:
            n = self._pins.get(job_id, 0) - 1
            if n > 0:
                self._pins[job_id] = n
            else:
                self._pins.pop(job_id, None)

    def cleanup(self, now: float | None = None) -> list[str]:
        """Remove finished jobs' folders beyond the newest ``keep`` or older than ``ttl`` (module
        doc), and forget those jobs. Returns the ids removed."""
        now = time.time() if now is None else now
        with self._cond:
            busy = set(self._reserved) | set(self._pins)
            for j in self._jobs.values():
                if j.state not in FINISHED:
                    busy.add(j.id)
                    busy.update(j.uses)
            known = {j.id: j for j in self._jobs.values()}
        candidates = []  # (finished time, id, folder)
        try:
            entries = list(os.scandir(self.root))
        except OSError:
            return []
        for e in entries:
            if not JOB_ID.match(e.name) or e.name in busy or not e.is_dir(follow_symlinks=False):
                continue  # only real folders named as jobs, directly under the jobs root
            job = known.get(e.name)
            if job is not None:
                when = job.finished or job.created
            else:
                try:
                    when = e.stat(follow_symlinks=False).st_mtime
                except OSError:
                    continue
            candidates.append((when, e.name, Path(e.path)))
        candidates.sort(reverse=True)
        removed = []
        for k, (when, job_id, folder) in enumerate(candidates):
            if (self.keep is not None and k >= self.keep) or (self.ttl is not None and now - when > self.ttl):
                with self._cond:  # not taken by a new job meanwhile
                    if job_id in self._reserved or job_id in self._pins or (
                            job_id in self._jobs and self._jobs[job_id].state not in FINISHED):
                        continue
                self._remove(folder)
                with self._cond:  # forgotten once its folder is gone: a job that is no longer listed has no folder
                    self._jobs.pop(job_id, None)
                removed.append(job_id)
        return removed

    def _cleaner(self, interval: float) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._closed, timeout=interval)
                if self._closed:
                    return
            try:
                self.cleanup()
            except Exception:  # noqa: BLE001 - the next round tries again
                pass

    def _remove(self, folder: Path) -> None:
        """Remove a job folder: only a real folder directly under the jobs root, named as a job."""
        folder = Path(folder)
        if folder.parent != self.root or not JOB_ID.match(folder.name) or folder.is_symlink():
            raise ValueError(f"not a job folder of this studio: {folder}")
        shutil.rmtree(folder, ignore_errors=True)

    @staticmethod
    def _kill(proc: subprocess.Popen) -> None:
        """Stop a step's process group: SIGTERM, then SIGKILL after KILL_GRACE s."""
        for sig, wait in ((signal.SIGTERM, KILL_GRACE), (signal.SIGKILL, 10.0)):
            try:
                os.killpg(proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                return
            try:
                proc.wait(wait)
                # the leader has ended; the rest of its group gets the same signal once more
                try:
                    os.killpg(proc.pid, sig)
                except (ProcessLookupError, PermissionError):
                    pass
                return
            except subprocess.TimeoutExpired:
                continue

    def get(self, job_id: str) -> Job | None:
        """The job of ``job_id``, or None (also for a string that is not a job id)."""
        if not isinstance(job_id, str) or not JOB_ID.match(job_id):
            return None
        with self._cond:
            return self._jobs.get(job_id)

    def position(self, job_id: str) -> int | None:
        """0 for the next job to run, 1 for the one after, ...; None when not waiting."""
        with self._cond:
            try:
                return self._waiting.index(job_id)
            except ValueError:
                return None

    def jobs(self, kind: str | None = None, state: str | None = None) -> list[Job]:
        with self._cond:
            return [j for j in self._jobs.values() if (kind is None or j.kind == kind)
                    and (state is None or j.state == state)]

    def file(self, job_id: str, name: str) -> Path | None:
        """The path of a job's output ``name``, looked up in the job's own table (the request's
        string is a key, never a part of a path); None when there is no such file."""
        job = self.get(job_id)
        if job is None or not isinstance(name, str) or name not in job.outputs:
            return None
        path = job.folder / job.outputs[name]
        return path if path.is_file() else None

    def close(self) -> None:
        """Stop the workers and the clean-up; a running command is terminated (its process group)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
            procs = list(self._procs.values())
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except (ProcessLookupError, PermissionError):
                pass

    # -- running them ---------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._waiting and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job = self._jobs[self._waiting.popleft()]
                job.state, job.started = "running", time.time()
            try:
                for k, step in enumerate(job.steps):
                    if job.cancelling:
                        break
                    job.step, job.stage, job.progress = k, step.label, 0.0
                    self._run_step(job, step)
                    if job.error or job.cancelling:
                        break
            except Exception as e:  # noqa: BLE001 - a job's failure is its own, the worker goes on
                job.error = f"internal error: {type(e).__name__}: {e}"
            if job.cancelling:  # its command has ended: nothing writes to the folder any more
                self._remove(job.folder)
                job.error = None
            job.finished = time.time()
            job.state = "cancelled" if job.cancelling else "failed" if job.error else "done"
            if job.state == "done":
                job.progress = 1.0

    def _run_step(self, job: Job, step: Step) -> None:
        # a session of its own: cancelling stops the command and whatever it started (its process group)
        proc = subprocess.Popen(step.argv, cwd=job.folder, env=self.env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
        with self._cond:
            self._procs[job.id] = proc
            cancelled = job.cancelling  # cancelled while it was being started
        if cancelled:
            threading.Thread(target=self._kill, args=(proc,), daemon=True).start()
        out: list[bytes] = []
        reader = threading.Thread(target=lambda: out.append(proc.stdout.read()), daemon=True)
        reader.start()
        lines: list[str] = []
        buf = b""
        while True:
            chunk = proc.stderr.read1(4096)
            if not chunk:
                break
            buf += chunk
            *parts, buf = re.split(rb"[\r\n]", buf)  # tqdm redraws with \r, messages end with \n
            for raw in parts:
                self._read_line(job, raw.decode("utf-8", "replace"), lines)
        self._read_line(job, buf.decode("utf-8", "replace"), lines)
        code = proc.wait()
        reader.join()
        with self._cond:
            self._procs.pop(job.id, None)
        if code != 0 and not job.cancelling:
            job.error = self._message(job, lines, code)
            return
        text = b"".join(out).decode("utf-8", "replace").strip()
        if text.startswith("{"):
            import json

            try:
                job.result[step.label] = json.loads(text)
            except ValueError:
                pass

    @staticmethod
    def _read_line(job: Job, line: str, lines: list[str]) -> None:
        line = line.strip()
        if not line:
            return
        m = _BAR.match(line)
        if m:
            total = max(1, int(m["total"]))
            job.progress = min(1.0, int(m["n"]) / total)
            stage = _STAGE.search(m["rest"])
            job.stage = f"{job.steps[job.step].label}: {stage.group(1).strip()}" if stage else job.steps[job.step].label
            return
        lines.append(line)
        del lines[:-50]  # the last lines are enough for the message

    def _message(self, job: Job, lines: list[str], code: int) -> str:
        """The failed command's one line, without the ``facetex: error:`` prefix and without the
        job folder's path (names inside the job remain)."""
        msg = next((ln for ln in reversed(lines) if ln.startswith("facetex: ")), None)
        if msg is None:
            msg = f"{job.steps[job.step].label} failed (exit code {code})"
        else:
            msg = re.sub(r"^facetex: (error: )?", "", msg)
        msg = msg.replace(str(job.folder) + os.sep, "").replace(str(job.folder), ".")
        return msg.replace(str(self.root) + os.sep, "")  # another job's file (a persona): <id>/name
