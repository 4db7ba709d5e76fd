# cutwatch live service.
#   Docker host:  docker build -t cutwatch .
#                 docker run --rm -p 8000:8000 -e CUTWATCH_TOKEN=$(openssl rand -hex 16) cutwatch
#   (the viser 3D view is at /viser/ on the same port; viser itself listens on the
#   container's loopback only)
#   here (buildah, no daemon, no registry):  make image && make run-image   (docs/deploy.md)
# The service binds 0.0.0.0 inside the container, so it refuses to start without
# CUTWATCH_TOKEN; mutating endpoints then need "Authorization: Bearer <token>".
#
# PIP_CERT: a CA bundle pip (and npm) trust, for a build behind a TLS-inspecting proxy;
# empty by default (a Docker host needs nothing). `make image` mounts the host's bundle.

# --- the dashboard's npm asset (uPlot) and the CNC NodeSet, from the lockfile
FROM debian:bookworm-slim AS web
ARG PIP_CERT=""
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        nodejs npm ca-certificates \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /web
COPY web/package.json web/package-lock.json ./
RUN if [ -n "$PIP_CERT" ]; then export NODE_EXTRA_CA_CERTS="$PIP_CERT"; fi \
    && npm ci --no-audit --no-fund --loglevel=error

# --- the virtual environment: pinned dependencies, then the package (editable at /app, so
# the app finds web/ beside server/ as in a checkout)
FROM debian:bookworm-slim AS venv
ARG PIP_CERT=""
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        python3 python3-venv \
    && rm -rf /var/lib/apt/lists/*
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /app
COPY pyproject.toml constraints.txt README.md ./
RUN python3 -m venv /opt/venv \
    && python3 -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" > /tmp/requirements.txt \
    && /opt/venv/bin/pip install ${PIP_CERT:+--cert "$PIP_CERT"} \
        -c constraints.txt -r /tmp/requirements.txt
COPY common ./common
COPY machine ./machine
COPY estimators ./estimators
COPY harness ./harness
COPY server ./server
# then without what only installs or tests need: pip, setuptools, the packages' own test
# suites (71 MB: scipy, numpy, numba, matplotlib)
RUN /opt/venv/bin/pip install ${PIP_CERT:+--cert "$PIP_CERT"} --no-deps -e . \
    && /opt/venv/bin/pip uninstall -q -y setuptools pip \
    && find /opt/venv -type d -name tests -prune -exec rm -rf {} + \
    && rm -rf build *.egg-info

# --- the service: Python from Debian, the venv and the code; no pip, npm or compilers
FROM debian:bookworm-slim
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends python3 \
    && rm -rf /var/lib/apt/lists/* \
    && useradd --create-home --uid 10001 --user-group --shell /usr/sbin/nologin cutwatch
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1 \
    NUMBA_CACHE_DIR=/opt/numba-cache MPLCONFIGDIR=/tmp/matplotlib \
    CUTWATCH_DATA_DIR=/var/lib/cutwatch
COPY --from=venv /opt/venv /opt/venv
COPY --from=venv /app /app
COPY web /app/web
COPY --from=web /web/node_modules/uplot /app/web/node_modules/uplot
# the CNC NodeSet (OPC 40502) `cutwatch opcua-sim` imports (docs/opcua.md)
COPY --from=web /web/node_modules/node-opcua-nodesets/nodesets/Opc.Ua.CNC.NodeSet.xml \
     /app/web/node_modules/node-opcua-nodesets/nodesets/Opc.Ua.CNC.NodeSet.xml
WORKDIR /app
# the numba kernels of the live scenarios compiled once here, not at every start (the
# cache is keyed by CPU: another CPU recompiles into it, hence writable by any user)
RUN python -c "from server.pipeline.live_pipeline import SCENARIOS, LivePipeline; \
[LivePipeline(name).step(125) for name in SCENARIOS for _ in range(3)]" \
    && chmod -R a+rwX /opt/numba-cache \
    && install -d -o cutwatch -g cutwatch /var/lib/cutwatch
# recordings, uploads and reports (mount a volume here to keep them: -v DIR:/var/lib/cutwatch)
USER cutwatch
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import json, os, urllib.request as u; port = os.environ.get('CUTWATCH_PORT', '8000'); assert json.load(u.urlopen(f'http://127.0.0.1:{port}/api/health', timeout=4))['status'] in ('ok', 'degraded')"]
ENTRYPOINT ["cutwatch", "serve", "--host", "0.0.0.0"]
