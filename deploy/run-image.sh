#!/usr/bin/env bash
# Run the image cutwatch:latest here, without a container engine: `buildah run` in a fresh
# working container (removed on exit). Chroot isolation shares the host's network, so the
# image's `cutwatch serve --host 0.0.0.0` is given `--host 127.0.0.1`: the service answers
# on the host's loopback only. Ctrl-C (or SIGTERM) stops the service cleanly.
#   PORT=8000 VISER_PORT=8080 CUTWATCH_TOKEN=... deploy/run-image.sh [extra serve options]
# CUTWATCH_TOKEN is required by mutating endpoints; one is generated when unset.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=deploy/common.sh
source deploy/common.sh
IMAGE=${IMAGE:-cutwatch:latest}
PORT=${PORT:-8000}
VISER_PORT=${VISER_PORT:-8080}
if [ -z "${CUTWATCH_TOKEN:-}" ]; then
    CUTWATCH_TOKEN=$(head -c 18 /dev/urandom | base64 | tr '+/' '-_')
    echo "CUTWATCH_TOKEN=$CUTWATCH_TOKEN (generated; every request but /api/health needs it: a Bearer token, or log in at /login)"
fi

ctr=$(bh from --pull-never "$IMAGE")
server=""
runner=""
stopping=0
stop() {
    # like `docker stop`: SIGTERM to the service itself (buildah run would kill it)
    stopping=1
    if [ -n "$server" ] && kill -0 "$server" 2>/dev/null; then kill -TERM "$server"; fi
}
cleanup() {
    stop
    [ -n "$runner" ] && wait "$runner" 2>/dev/null || true
    bh rm "$ctr" >/dev/null 2>&1 || true
}
trap stop INT TERM
trap cleanup EXIT

# shellcheck disable=SC2207  # the entrypoint's words have no spaces
entrypoint=($(bh inspect --type image --format '{{range .Docker.Config.Entrypoint}}{{.}} {{end}}' "$IMAGE"))
# its own session: a terminal's Ctrl-C reaches this script, which stops the service
setsid buildah --storage-driver vfs run --isolation chroot \
    --env "CUTWATCH_TOKEN=$CUTWATCH_TOKEN" --env "CUTWATCH_PORT=$PORT" \
    --env "CUTWATCH_VISER_PORT=$VISER_PORT" \
    "$ctr" -- "${entrypoint[@]}" --host 127.0.0.1 "$@" &
runner=$!
# the service is the innermost process under buildah run (runtime, exec, python)
for _ in $(seq 1 100); do
    p=$runner
    while c=$(pgrep -P "$p" | head -n1) && [ -n "$c" ]; do p=$c; done
    case "$(tr '\0' ' ' 2>/dev/null <"/proc/$p/cmdline")" in
        *buildah*) ;;
        *cutwatch*) server=$p; break ;;
    esac
    sleep 0.1
done
echo "cutwatch in $IMAGE: http://127.0.0.1:$PORT/  (viser 3D view http://127.0.0.1:$PORT/viser/)"
status=0
wait "$runner" || status=$?
# `wait` returns early when a trapped signal arrives: wait for the service's own exit
while kill -0 "$runner" 2>/dev/null; do wait "$runner" || status=$?; done
# uvicorn ends by re-raising the SIGTERM it handled, which buildah reports as status 1
if [ "$stopping" = 1 ]; then echo "stopped"; exit 0; fi
exit "$status"
