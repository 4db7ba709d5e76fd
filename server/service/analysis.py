"""Residual analyses of the service's logs as background jobs (``POST /api/analyses``).

A job runs ``cutwatch residual LOG --out DIR`` in a child process: the very command a
user runs, so the analysis the service offers is the command line's, whatever changes
there (one entry point), and its CPU-heavy work never holds the live loop's interpreter.
One job at a time. The report goes to a hidden directory in the reports area and is
renamed into place (``reports/<name>/``) when the command succeeds, so a report exists
whole or not at all.

Progress: the command reports each analysis step (the nominal model, each candidate
effect) on its progress bar; a job's ``progress`` is the steps seen over the most steps
the analysis can take (every family in every selection round), 0.05 once the process
runs, 1 when the report is in place. It never runs ahead of the work; it may jump to 1
when the selection stops early.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

from server.records.data_areas import DataStore

#: the project root (the child process loads the service's own code)
ROOT = Path(__file__).resolve().parents[2]
#: a job that runs longer is stopped
TIMEOUT_S = 900.0
_STEP_RE = re.compile(r"residual:\s*(\d+)\s*step")


def max_steps(kind: str | None) -> int:
    """The most progress steps of an analysis of ``kind`` (1 + families x rounds)."""
    from estimators.residual import rigid as residual
    from estimators.residual import two_inertia as residual_two_inertia

    if kind == "rigid":
        return 2 + len(residual.FAMILIES) * residual.RigidModel.max_effects
    two = residual_two_inertia
    return 1 + len(two.FAMILIES) * two.TwoInertiaModel.max_effects


class AnalysisOptions(TypedDict):
    """What a request chose for its analysis (``cutwatch residual``'s options)."""

    holdout: float | None  # share of the log kept back for validation (None: the default)
    kind: str | None  # the log's model kind (None: its sidecar's)


@dataclass
class Job:
    """One analysis: its request, its state and, when done, what the report selected."""

    id: str
    log: str
    area: str
    report: str
    options: AnalysisOptions
    state: str = "queued"  # queued, running, done, failed
    progress: float = 0.0
    step: str = ""
    message: str = ""
    started: float = field(default_factory=time.time)
    finished: float | None = None
    selected: list[str] = field(default_factory=list)
    observer_effects: int = 0
    rms_before: float | None = None
    rms_after: float | None = None

    def view(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["report_url"] = f"/residual/{self.report}/" if self.state == "done" else None
        return d


class Busy(Exception):
    """An analysis is running already."""

    def __init__(self, job: Job) -> None:
        self.job = job
        super().__init__(f"an analysis is running already (job {job.id} on {job.log!r})")


class Analyses:
    """The jobs of one service: one runs at a time; the last ``keep`` are remembered."""

    def __init__(self, store: DataStore, keep: int = 20) -> None:
        self.store = store
        self.keep = keep
        self.jobs: dict[str, Job] = {}
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._closed = False

    def running(self) -> Job | None:
        with self._lock:
            return next((j for j in self.jobs.values() if j.state in ("queued", "running")), None)

    def report_name(self, wanted: str) -> str:
        """``wanted``, or ``wanted-2``, ``-3``... when a report of that name exists."""
        base = self.store.area("reports")
        name, k = wanted, 1
        while (base / name).exists():
            k += 1
            name = f"{wanted}-{k}"
        return name

    def submit(
        self, log_path: Path, log: str, area: str, report: str, options: AnalysisOptions
    ) -> Job:
        """Start an analysis of ``log_path`` into the report ``report``.

        Raises
        ------
        Busy
            Another job is queued or running.
        """
        with self._lock:
            busy = next((j for j in self.jobs.values() if j.state in ("queued", "running")), None)
            if busy is not None:
                raise Busy(busy)
            job = Job(uuid.uuid4().hex[:12], log, area, report, options.copy())
            self.jobs[job.id] = job
            for old in list(self.jobs)[: max(0, len(self.jobs) - self.keep)]:
                del self.jobs[old]
        threading.Thread(
            target=self._run, args=(job, log_path), name=f"analysis-{job.id}", daemon=True
        ).start()
        return job

    def close(self) -> None:
        """Stop a running job (service shutdown)."""
        self._closed = True
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()

    # ------------------------------------------------------------------ the job
    def _command(self, job: Job, log_path: Path, out: Path) -> list[str]:
        cmd = [sys.executable, "-c", "from server.cli.main import main; raise SystemExit(main())"]
        # the log by its name, run beside it: report.json's "log" names no server path
        cmd += ["residual", log_path.name, "--out", str(out)]
        holdout, kind = job.options.get("holdout"), job.options.get("kind")
        if holdout is not None:
            cmd += ["--holdout", repr(float(holdout))]
        if kind is not None:
            cmd += ["--kind", str(kind)]
        return cmd

    def _run(self, job: Job, log_path: Path) -> None:
        reports = self.store.area("reports").resolve()  # absolute: the command runs elsewhere
        out = reports / f".job-{job.id}"
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
        env["PYTHONUNBUFFERED"] = "1"
        kind = job.options.get("kind") or _sidecar_kind(log_path)
        bound = max(1, max_steps(kind))
        tail = ""
        proc: subprocess.Popen[bytes] | None = None
        try:
            proc = subprocess.Popen(
                self._command(job, log_path, out),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                env=env,
                cwd=str(log_path.parent),
            )
            self._proc = proc
            job.state, job.progress = "running", 0.05
            deadline = time.monotonic() + TIMEOUT_S
            if proc.stderr is None:  # never: stderr=PIPE above
                raise RuntimeError("no stderr pipe")
            fd = proc.stderr.fileno()
            while True:
                chunk = os.read(fd, 4096)
                if not chunk:
                    break
                tail = (tail + chunk.decode("utf-8", "replace"))[-8192:]
                steps = [int(m) for m in _STEP_RE.findall(tail)]
                if steps:
                    job.progress = max(job.progress, min(0.95, 0.05 + 0.9 * max(steps) / bound))
                    post = re.findall(r"step/s, ([^\]\r\n]+)\]", tail)
                    job.step = post[-1] if post else job.step
                if time.monotonic() > deadline:
                    proc.kill()
            rc = proc.wait()
            if self._closed:
                raise RuntimeError("the service stopped")
            if rc != 0 or not (out / "report.json").is_file():
                job.state = "failed"
                job.message = _error_line(tail, rc, log_path, job.log, out)
                return
            final = reports / self.report_name(job.report)
            os.replace(out, final)
            job.report = final.name
            _summarise(job, final / "report.json")
            job.state, job.progress, job.step = "done", 1.0, "report written"
        except Exception as exc:  # keep the service up and say why the job failed
            job.state, job.message = "failed", f"{type(exc).__name__}: {exc}"
        finally:
            if proc is not None and proc.stderr is not None:
                proc.stderr.close()
            self._proc = None
            job.finished = time.time()
            if out.exists():
                shutil.rmtree(out, ignore_errors=True)


def _sidecar_kind(log_path: Path) -> str | None:
    with contextlib.suppress(OSError, ValueError, AttributeError):
        k = json.loads(log_path.with_suffix(".json").read_text()).get("kind")
        return k if isinstance(k, str) else None
    return None


def _error_line(tail: str, rc: int, log_path: Path, log: str, out: Path) -> str:
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", tail) if ln.strip()]
    errs = [ln for ln in lines if ": error: " in ln]
    msg = errs[-1] if errs else (lines[-1] if lines else f"exit status {rc}")
    msg = msg.split(": error: ", 1)[-1]
    return msg.replace(str(log_path), log).replace(str(out), "the report")[:1000]


def _summarise(job: Job, report_json: Path) -> None:
    with contextlib.suppress(OSError, ValueError):
        rep = json.loads(report_json.read_text())
        job.selected = [str(s) for s in rep.get("selected", [])]
        job.observer_effects = len(rep.get("observer_effects") or [])
        for k in ("rms_before", "rms_after"):
            v = rep.get(k)
            setattr(job, k, float(v) if isinstance(v, int | float) else None)
