"""The residual loop from the service: ``POST /api/analyses`` runs ``cutwatch residual``
on a recording or an upload (by name) as a background job; ``GET /api/analyses/{id}``
says how far it is; the report lands in the reports area (``/residual/{report}/``)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, Request

from server.records.data_areas import check_name
from server.service.analysis import Analyses, AnalysisOptions, Busy
from server.service.datafiles import find_log
from server.service.deps import Authorised, Store, conflict
from server.service.http_errors import FieldError, error
from server.service.schemas import AnalysisBody, AnalysisJob, AnalysisJobs, error_responses

router = APIRouter(prefix="/api/analyses", tags=["analyses"], responses=error_responses())

_REPORT_RULE = "a plain name: 1-120 of A-Z a-z 0-9 _ . - starting with a letter or digit"


def jobs(request: Request) -> Analyses:
    a: Analyses = request.app.state.analyses
    return a


@router.post(
    "",
    summary="analyse a recording or an upload (cutwatch residual) as a background job",
    dependencies=[Authorised],
    response_model=AnalysisJob,
    status_code=202,
    responses=error_responses(409, 413, 422),
)
def start_analysis(body: AnalysisBody, request: Request, st: Store) -> AnalysisJob:
    area, path = find_log(st, body.log, body.area)
    wanted = body.report if body.report is not None else Path(path.name).stem
    if not check_name(wanted):
        raise FieldError("report", _REPORT_RULE, body.report, f"report: expected {_REPORT_RULE}")
    a = jobs(request)
    options = AnalysisOptions(holdout=body.holdout, kind=body.kind)
    try:
        job = a.submit(path, path.name, area, a.report_name(wanted), options)
    except Busy as exc:
        raise conflict(
            "log", "a new job once the running one is done", body.log, str(exc)
        ) from None
    return AnalysisJob.model_validate(job.view())


@router.get("", summary="recent analysis jobs", response_model=AnalysisJobs)
def list_analyses(request: Request) -> AnalysisJobs:
    return AnalysisJobs(
        jobs=[AnalysisJob.model_validate(j.view()) for j in jobs(request).jobs.values()]
    )


@router.get(
    "/{job_id}",
    summary="one analysis job: state and progress",
    response_model=AnalysisJob,
    responses=error_responses(404),
)
def get_analysis(job_id: str, request: Request) -> AnalysisJob:
    job = jobs(request).jobs.get(job_id)
    if job is None:
        msg = f"no analysis job {job_id!r} (GET /api/analyses lists them)"
        raise HTTPException(
            404, detail=[error("job_id", "a job id from POST /api/analyses", job_id, msg)]
        )
    return AnalysisJob.model_validate(job.view())
