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
# docker format: OCI image configs have no HEALTHCHECK. No --layers: on vfs every cached
# step is a full copy of its file system (a fully cached rebuild wrote 15 GB and was
# slower than building afresh). The host's CA bundle is mounted
# for pip/npm (a TLS-inspecting proxy's CA is in it); it does not end up in the image.
bh bud --isolation chroot --pull-never --format docker \
    -v "$CA:/host-ca.crt:ro" --build-arg PIP_CERT=/host-ca.crt \
    -t "$IMAGE" .
# the image this one replaced, now untagged
bh rmi --prune >/dev/null 2>&1 || true
