#!/usr/bin/env bash
# Compose smoke test (not part of `./dev test`): a real cluster in containers renders the Cornell
# box through the API while one of its workers is killed, and the image must equal the CLI's.
#
#   docker/smoke-test.sh
#
# 1. A Docker engine: the one DOCKER_HOST (or the default socket) names, else a private one
#    started by docker/start-engine.sh (and stopped again at the end).
# 2. A compose: $COMPOSE if set (e.g. COMPOSE="docker compose"), else `docker compose`, else
#    `docker-compose`, else docker-compose 1.29.2 installed by docker/install-compose.sh.
# 3. The image, built by compose from this checkout (classic builder). Its base: $BASE_IMAGE if
#    set, else python:3.11-slim-bookworm if the engine has it or can pull it, else
#    local/debian-python:bookworm made by docker/local-base-image.sh. The host's extra CA
#    certificates (/usr/local/share/ca-certificates/*.crt) are copied to docker/ca-certificates/
#    unless SMOKE_HOST_CA=0.
# 4. The reference: `tilerender render` of the Cornell box in a container of the image (an
#    embedded Ray), and with this checkout's .venv if it has one (SMOKE_HOST_CLI=path overrides,
#    SMOKE_HOST_CLI=none skips).
# 5. `up` with 2 workers of 1 CPU each, Ray token auth and an API token, on a free local port;
#    waits for every healthcheck; docker/smoke_client.py uploads the scene, submits a
#    SPP x 256x256 job, `docker kill`s a worker container KILL_AFTER s into it, waits for the
#    job and downloads its NPY; the arrays must be equal bit for bit.
# 6. `down -v`, always (and the logs first, on a failure). Exit 0 only if everything passed.
#
# Environment: COMPOSE, BASE_IMAGE, SMOKE_SPP (256), SMOKE_KILL_AFTER (3 s), SMOKE_TIMEOUT (600 s
# per wait), SMOKE_PROJECT (tilerender-smoke), SMOKE_KEEP_ENGINE=1 (leave a started engine up),
# SMOKE_HOST_CA, SMOKE_HOST_CLI, DOCKER_BUILDKIT (0).
set -euo pipefail

HERE=$(cd "$(dirname "$0")" && pwd)
REPO=$(dirname "$HERE")
PROJECT=${SMOKE_PROJECT:-tilerender-smoke}
IMAGE=${TILERENDER_IMAGE:-tilerender:local}
SPP=${SMOKE_SPP:-256}
SIZE=256
SEED=3
WORKERS=2
KILL_AFTER=${SMOKE_KILL_AFTER:-3}
TIMEOUT=${SMOKE_TIMEOUT:-600}
OFFICIAL_BASE=python:3.11-slim-bookworm
LOCAL_BASE=local/debian-python:bookworm
export DOCKER_BUILDKIT=${DOCKER_BUILDKIT:-0} COMPOSE_DOCKER_CLI_BUILD=${COMPOSE_DOCKER_CLI_BUILD:-0}

START=$SECONDS
PHASE_START=$SECONDS
PHASES=()
WORK=$(mktemp -d "${TMPDIR:-/tmp}/tilerender-smoke.XXXXXX")
chmod 0777 "$WORK"
STARTED_ENGINE=0
UP=0
STATUS=1

log() { printf 'smoke [%4ds] %s\n' $((SECONDS - START)) "$*" >&2; }
fail() {
    log "FAILED: $*"
    exit 1
}
phase() {
    PHASES+=("$1 $((SECONDS - PHASE_START))s")
    PHASE_START=$SECONDS
}

compose() {
    # shellcheck disable=SC2086
    $COMPOSE -f "$HERE/docker-compose.yml" --env-file "$WORK/smoke.env" -p "$PROJECT" "$@"
}

teardown() {
    local code=$?
    set +e
    if [ "$UP" = 1 ]; then
        if [ "$STATUS" != 0 ]; then
            log "service logs (last 60 lines each):"
            compose logs --no-color --tail=60 >&2
        fi
        log "tearing down"
        compose down -v --remove-orphans >/dev/null 2>&1 || log "warning: compose down failed"
        phase down
    fi
    if [ "$STARTED_ENGINE" = 1 ] && [ "${SMOKE_KEEP_ENGINE:-0}" != 1 ]; then
        "$HERE/start-engine.sh" stop
        phase engine-stop
    fi
    rm -rf "$WORK"
    if [ "$STATUS" = 0 ]; then
        log "PASSED in $((SECONDS - START)) s (${PHASES[*]})"
    else
        log "FAILED after $((SECONDS - START)) s (exit $code)"
    fi
}
trap teardown EXIT
trap 'exit 130' INT TERM

# 1. The engine -------------------------------------------------------------------------------
if docker info >/dev/null 2>&1; then
    log "using the Docker engine at ${DOCKER_HOST:-the default socket}"
elif "$HERE/start-engine.sh" status 2>/dev/null; then
    log "using the engine docker/start-engine.sh started before (it stays up)"
    eval "$("$HERE/start-engine.sh")"
else
    log "no Docker engine answers: starting one (docker/start-engine.sh)"
    eval "$("$HERE/start-engine.sh")"
    STARTED_ENGINE=1
fi
docker info >/dev/null 2>&1 || fail "the Docker engine does not answer"
phase engine

# 2. Compose ------------------------------------------------------------------------------------
if [ -z "${COMPOSE:-}" ]; then
    if docker compose version >/dev/null 2>&1; then
        COMPOSE="docker compose"
    elif command -v docker-compose >/dev/null; then
        COMPOSE=docker-compose
    else
        COMPOSE=$("$HERE/install-compose.sh" v1)
    fi
fi
VERSION=$($COMPOSE version 2>/dev/null) || fail "compose '$COMPOSE' does not run"
VERSION=${VERSION%%$'\n'*}
log "compose: $COMPOSE ($VERSION)"
phase compose

# 3. The image ----------------------------------------------------------------------------------
if [ -z "${BASE_IMAGE:-}" ]; then
    if docker image inspect "$OFFICIAL_BASE" >/dev/null 2>&1; then
        BASE_IMAGE=$OFFICIAL_BASE
    elif docker image inspect "$LOCAL_BASE" >/dev/null 2>&1; then
        BASE_IMAGE=$LOCAL_BASE
    elif timeout 60 docker pull -q "$OFFICIAL_BASE" >/dev/null 2>&1; then
        BASE_IMAGE=$OFFICIAL_BASE
    else
        log "cannot pull $OFFICIAL_BASE: making $LOCAL_BASE (docker/local-base-image.sh)"
        "$HERE/local-base-image.sh"
        BASE_IMAGE=$LOCAL_BASE
    fi
fi
phase base-image
HOST_CAS=/usr/local/share/ca-certificates
if [ "${SMOKE_HOST_CA:-1}" != 0 ] && compgen -G "$HOST_CAS/*.crt" >/dev/null; then
    cp "$HOST_CAS"/*.crt "$HERE/ca-certificates/"
    log "trusting the host's extra CA certificates in the image (SMOKE_HOST_CA=0: don't)"
fi
TOKEN=$(od -An -N16 -tx1 /dev/urandom | tr -d ' \n')
RAY_TOKEN=$(od -An -N16 -tx1 /dev/urandom | tr -d ' \n')
PORT=$(python3 -c '
import socket
s = socket.socket()
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1])')
cat >"$WORK/smoke.env" <<EOF
TILERENDER_IMAGE=$IMAGE
BASE_IMAGE=$BASE_IMAGE
TILERENDER_PORT=$PORT
TILERENDER_TOKEN=$TOKEN
RAY_AUTH_MODE=token
RAY_AUTH_TOKEN=$RAY_TOKEN
RAY_WORKER_CPUS=1
API_WAIT_WORKERS=$WORKERS
EOF
log "building $IMAGE on $BASE_IMAGE"
compose build ray-head >"$WORK/build.log" 2>&1 || {
    tail -n 40 "$WORK/build.log" >&2
    fail "the image did not build"
}
phase build

# 4. The reference ------------------------------------------------------------------------------
FLAGS=(--spp "$SPP" --width "$SIZE" --height "$SIZE" --seed "$SEED" -q)
log "reference: tilerender render in a container (${SIZE}x$SIZE, $SPP spp, seed $SEED)"
docker run --rm --init --shm-size=1g -v "$WORK:/work" "$IMAGE" \
    tilerender render /opt/tilerender/scenes/cornell-box/scene.json -o /work/reference.npy \
    "${FLAGS[@]}" || fail "the reference render failed"
HOST_CLI=${SMOKE_HOST_CLI:-$REPO/.venv/bin/tilerender}
if [ "$HOST_CLI" != none ] && [ -x "$HOST_CLI" ]; then
    log "reference: $HOST_CLI render on the host"
    "$HOST_CLI" render "$REPO/scenes/cornell-box/scene.json" -o "$WORK/host.npy" "${FLAGS[@]}" ||
        fail "the host's render failed"
else
    log "no host CLI ($HOST_CLI): comparing with the container's render only"
fi
phase reference

# 5. The cluster --------------------------------------------------------------------------------
log "up: head, $WORKERS workers, api on 127.0.0.1:$PORT"
UP=1
compose up -d --no-build --scale "ray-worker=$WORKERS" >"$WORK/up.log" 2>&1 || {
    cat "$WORK/up.log" >&2
    fail "compose up failed"
}
mapfile -t CONTAINERS < <(compose ps -q)
[ "${#CONTAINERS[@]}" -eq $((WORKERS + 2)) ] ||
    fail "expected $((WORKERS + 2)) containers, compose shows ${#CONTAINERS[@]}"
HEALTH='{{if .State.Health}}{{.State.Health.Status}}{{else}}none{{end}}'
deadline=$((SECONDS + TIMEOUT))
while :; do
    unhealthy=0
    for id in "${CONTAINERS[@]}"; do
        health=$(docker inspect --format "$HEALTH" "$id")
        [ "$health" = healthy ] || unhealthy=$((unhealthy + 1))
    done
    [ "$unhealthy" = 0 ] && break
    [ $SECONDS -lt $deadline ] || fail "$unhealthy container(s) not healthy after $TIMEOUT s"
    sleep 2
done
log "all $((WORKERS + 2)) containers healthy"
phase up

mapfile -t WORKER_IDS < <(compose ps -q ray-worker)
VICTIM=${WORKER_IDS[0]}
log "job: ${SIZE}x$SIZE at $SPP spp through the API; kill ${VICTIM:0:12} after ${KILL_AFTER}s"
python3 "$HERE/smoke_client.py" --url "http://127.0.0.1:$PORT" --token "$TOKEN" \
    --scene-dir "$REPO/scenes/cornell-box" --spp "$SPP" --width "$SIZE" --height "$SIZE" \
    --seed "$SEED" --tracers "$WORKERS" --kill "docker kill $VICTIM" --kill-after "$KILL_AFTER" \
    --timeout "$TIMEOUT" --out "$WORK/api.npy" >"$WORK/job.json" || fail "the job through the API"
log "job: $(cat "$WORK/job.json")"
[ "$(docker inspect --format '{{.State.Running}}' "$VICTIM")" = false ] ||
    fail "the killed worker container is running again"
phase job

# The comparison, with the image's numpy: equal dtype, shape and every bit.
compare() {
    docker run --rm -v "$WORK:/work:ro" "$IMAGE" python -c '
import sys
import numpy as np
a, b = (np.load(f"/work/{name}") for name in sys.argv[1:])
print(f"{sys.argv[1]} {a.dtype}{a.shape} vs {sys.argv[2]} {b.dtype}{b.shape}: ", end="")
same = a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
print("bit-identical" if same else f"DIFFERENT (max |diff| {np.abs(a - b).max():.3g})")
sys.exit(not same)' "$1" "$2"
}
compare api.npy reference.npy || fail "the API's image differs from the CLI's render in the image"
if [ -f "$WORK/host.npy" ]; then
    compare api.npy host.npy || fail "the API's image differs from the host CLI's render"
fi
phase compare
STATUS=0
