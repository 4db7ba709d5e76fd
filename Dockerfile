# cutwatch live service. Build:  docker build -t cutwatch .
# Run:  docker run --rm -p 8000:8000 -p 8080:8080 -e CUTWATCH_TOKEN=change-me cutwatch
# (bound to 0.0.0.0 inside the container, so the service refuses to start without a token;
# mutating endpoints then need "Authorization: Bearer <token>")

# --- stage 1: the dashboard's npm assets, from the lockfile
FROM node:20-slim AS web
WORKDIR /web
COPY web/package.json web/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error

# --- stage 2: the service
FROM python:3.11-slim
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    NUMBA_CACHE_DIR=/tmp/numba-cache
RUN useradd --create-home --uid 10001 cutwatch
WORKDIR /app
# dependencies first (pinned by constraints.txt), then the code
COPY pyproject.toml constraints.txt README.md ./
RUN mkdir machine estimators server \
    && touch machine/__init__.py estimators/__init__.py server/__init__.py \
    && pip install -c constraints.txt . \
    && pip uninstall -y cutwatch && rm -rf machine estimators server build *.egg-info
COPY machine ./machine
COPY estimators ./estimators
COPY server ./server
COPY web ./web
COPY --from=web /web/node_modules ./web/node_modules
# editable: the app finds web/ next to the server package
RUN pip install --no-deps -c constraints.txt -e . && chown -R cutwatch /app
USER cutwatch
EXPOSE 8000 8080
HEALTHCHECK --interval=15s --timeout=3s --start-period=30s --retries=3 \
  CMD python -c "import json,urllib.request as u; \
assert json.load(u.urlopen('http://127.0.0.1:8000/api/health', timeout=2))['status'] == 'ok'"
ENTRYPOINT ["cutwatch", "serve", "--host", "0.0.0.0"]
