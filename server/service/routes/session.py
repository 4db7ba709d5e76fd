"""The browser's session: the login page, ``POST /api/login``, ``POST /api/logout``,
``GET /api/session`` (see :mod:`server.service.auth`)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, JSONResponse
from pydantic import BaseModel, Field

from server.service import auth
from server.service.http_errors import error
from server.service.schemas import error_responses

router = APIRouter(tags=["session"], responses=error_responses())

LOGIN_PAGE = Path(__file__).resolve().parents[3] / "web" / "login.html"
#: a refused login waits this long before answering (guessing slowed down)
FAIL_DELAY_S = 0.5


class Login(BaseModel):
    """``POST /api/login``: one of the service's tokens."""

    model_config = {"extra": "forbid"}
    token: str = Field(..., min_length=1, max_length=512, description="CUTWATCH_TOKEN or _VIEW_")


class Session(BaseModel):
    """Who this browser is: its role (None: not logged in) and whether tokens are set."""

    role: auth.Role | None
    access_control: bool = Field(description="false: no token set, everyone is operator")


@router.get("/login", include_in_schema=False)
def login_page() -> FileResponse:
    return FileResponse(LOGIN_PAGE, media_type="text/html")


@router.post(
    "/api/login",
    summary="log in with a token: sets an HttpOnly, SameSite=Strict session cookie",
    response_model=Session,
    responses=error_responses(413, 422),
)
async def login(body: Login, request: Request) -> JSONResponse:
    a = auth.access_of(request)
    if not a.enabled:
        return JSONResponse(Session(role="operator", access_control=False).model_dump())
    got = a.login(body.token)
    if got is None:
        await asyncio.sleep(FAIL_DELAY_S)
        msg = "this token is neither CUTWATCH_TOKEN nor CUTWATCH_VIEW_TOKEN"
        raise HTTPException(
            401, detail=[error("token", "a token of this service", "a token that does not match",
                               msg)]
        )  # fmt: skip
    sid, role = got
    resp = JSONResponse(Session(role=role, access_control=True).model_dump())
    resp.set_cookie(
        auth.COOKIE,
        sid,
        max_age=int(a.session_s),
        path="/",
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
    )
    return resp


@router.post("/api/logout", summary="end this browser's session", response_model=Session)
def logout(request: Request) -> JSONResponse:
    a = auth.access_of(request)
    sid = request.cookies.get(auth.COOKIE)
    if sid:
        a.logout(sid)
    resp = JSONResponse(Session(role=None, access_control=a.enabled).model_dump())
    resp.delete_cookie(auth.COOKIE, path="/", httponly=True, samesite="strict")
    return resp


@router.get("/api/session", summary="this browser's role", response_model=Session)
def session(request: Request) -> Session:
    a = auth.access_of(request)
    role, _ = a.role_of(request)
    return Session(role=role, access_control=a.enabled)
