#!/usr/bin/env bash
# Build the image cutwatch:latest from the Dockerfile with buildah (no daemon), on a local
# debian:bookworm-slim (deploy/base-image.sh). Installs buildah and debootstrap when
# missing (as root). IMAGE=name:tag overrides the tag.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=deploy/common.sh
source deploy/common.sh
IMAGE=${IMAGE:-cutwatch:latest}
CA=/etc/ssl/certs/ca-certificates.crt

need_root buildah debootstrap
deploy/base-image.sh
# chroot isolation: no user namespaces or runc needed, RUN steps use the host's network.
# docker format: OCI image configs have no HEALTHCHECK. --layers: steps whose inputs did
# not change are reused (a code change rebuilds from its COPY on). The host's CA bundle is mounted
# for pip/npm (a TLS-inspecting proxy's CA is in it); it does not end up in the image.
bh bud --isolation chroot --pull-never --format docker --layers \
    -v "$CA:/host-ca.crt:ro" --build-arg PIP_CERT=/host-ca.crt \
    -t "$IMAGE" .
