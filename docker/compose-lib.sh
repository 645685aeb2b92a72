# Shared by docker/compose-check.sh and docker/fault-test.sh (sourced, not run): finds a Docker
# engine and a Compose tool, and tears the project down on exit, printing its logs on failure.
# After sourcing, `compose ARGS...` runs Compose v2 (`docker compose`) or v1 (`docker-compose`)
# on the repository's compose.yaml (plus the files in COMPOSE_FILES) as project `hilbench`.

cd "$(dirname "${BASH_SOURCE[0]}")/.."
COMPOSE_PROJECT="${COMPOSE_PROJECT:-hilbench}"
COMPOSE_FILES=(-f compose.yaml "${COMPOSE_FILES[@]}")

# Prints why the Docker steps cannot run here and exits 0 (a skip, not a failure).
skip() {
    echo "$SCRIPT_NAME: SKIPPED: $1" >&2
    exit 0
}

if ! command -v docker >/dev/null 2>&1; then
    skip "no docker client on PATH (the compose checks need a Docker engine)"
fi
if ! docker info >/dev/null 2>&1; then
    skip "no Docker engine answers \`docker info\` (not running, or no permission)"
fi
if docker compose version >/dev/null 2>&1; then
    COMPOSE_TOOL=(docker compose)
elif command -v docker-compose >/dev/null 2>&1 && docker-compose version >/dev/null 2>&1; then
    COMPOSE_TOOL=(docker-compose)
else
    skip "neither \`docker compose\` (v2) nor \`docker-compose\` (v1) is installed"
fi

compose() {
    "${COMPOSE_TOOL[@]}" -p "$COMPOSE_PROJECT" "${COMPOSE_FILES[@]}" "$@"
}

# Stops and removes the project (containers, network, volumes) on any exit; on failure prints
# the services' logs first.
teardown() {
    local rc=$?
    if [ "$rc" -ne 0 ]; then
        echo "$SCRIPT_NAME: FAILED (exit $rc); logs of the services:" >&2
        compose logs --no-color --tail=200 >&2 || true
    fi
    compose down -v --remove-orphans >/dev/null 2>&1 || true
    exit "$rc"
}
trap teardown EXIT

# Fails the script with a message.
fail() {
    echo "$SCRIPT_NAME: $1" >&2
    exit 1
}

# Checks a summary.json with docker/check-summary.py (arguments as that script takes them).
check_summary() {
    command -v python3 >/dev/null 2>&1 || fail "checking the summary needs python3"
    python3 docker/check-summary.py "$@" || fail "the summary check failed"
}
