#!/usr/bin/env bash
# Team services for pcpg-dist, on one host: an MLflow tracking server on PostgreSQL with proxied
# artifacts, the Optuna study database on the same PostgreSQL server, and a Ray head node.
# Other machines join the Ray cluster with `services.sh join HEAD_IP:PORT`.
#
#   ops/services.sh start  [all|db|mlflow|ray]   create the databases, start the servers
#   ops/services.sh stop   [all|mlflow|ray]      stop what this script started (by pid)
#   ops/services.sh status [all|mlflow|ray]      exit 0 only if everything asked for is up
#   ops/services.sh env                          the exports that point `pcpg` at the services
#   ops/services.sh join HEAD_IP:PORT            a Ray worker node on another machine
#
# Every setting is an environment variable (defaults in brackets); see ops/README.md.
#   PCPG_HOST            [127.0.0.1] address MLflow binds to and Ray advertises (0.0.0.0 is refused
#                        for Ray: give this machine's address that other nodes can reach)
#   PCPG_PG_URL          [postgresql+psycopg2://postgres@127.0.0.1:5432] PostgreSQL server, no
#                        database name (a password may sit in the URL or in ~/.pgpass; ?options
#                        such as sslmode=require follow each database's name)
#   PCPG_MLFLOW_DB       [pcpg_mlflow]  MLflow's database (created if missing)
#   PCPG_OPTUNA_DB       [pcpg_optuna]  Optuna's database (created if missing; a separate database
#                        because MLflow and Optuna both keep an `alembic_version` table)
#   PCPG_MLFLOW_PORT     [5000]
#   PCPG_MLFLOW_WORKERS  [2]            uvicorn worker processes
#   PCPG_MLFLOW_ARTIFACTS [$PCPG_SERVICES_DIR/mlartifacts] where proxied artifacts are stored
#                        (a local path, or s3://..., gs://..., a mounted NFS folder)
#   PCPG_MLFLOW_AUTH     [none] `basic` runs `mlflow server --app-name basic-auth` (needs
#                        Flask-WTF, i.e. mlflow[auth], and MLFLOW_AUTH_ADMIN_PASSWORD on first start)
#   PCPG_MLFLOW_ARGS     []             extra arguments, e.g. "--allowed-hosts mlflow.lab.org"
#   PCPG_RAY_PORT        [6379]         the GCS port that `--ray-address HOST:PORT` names
#   PCPG_RAY_CPUS        [all]          CPUs this node offers to Ray
#   PCPG_RAY_AUTH_MODE   [token]        `token` (a token in ~/.ray/auth_token, created if missing,
#                        copied to every node and client) or `disabled`
#   PCPG_RAY_ARGS        []             extra `ray start` arguments
#   PCPG_RAY_TEMP        [/tmp/pcpg-ray-$UID] Ray's temp/session dir (keep it short: Unix sockets)
#   PCPG_SERVICES_DIR    [${XDG_STATE_HOME:-~/.local/state}/pcpg-services] pids, logs, auth config
#   PCPG_BIN             [<repo>/.venv/bin, else PATH] where python, mlflow and ray are; the word
#                        PATH takes them from $PATH (e.g. under `uv run --with 'flask-wtf<2'`)
#   PCPG_START_TIMEOUT   [300]          seconds to wait for a server to answer
#   PCPG_RAY_START_ATTEMPTS [3]         tries of `ray start` (its raylet must register within 30 s)
#
# Exit codes: 0 done; 1 a service failed while starting (its log is named); 2 refused before
# starting anything (a bad setting or argument, a port already taken, no Ray head to join).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
HOST="${PCPG_HOST:-127.0.0.1}"
PG_URL="${PCPG_PG_URL:-postgresql+psycopg2://postgres@127.0.0.1:5432}"
PG_URL="${PG_URL%/}"
# SQLAlchemy 2.1 reads a bare postgresql:// as psycopg 3, which is not installed; name psycopg2.
[[ "$PG_URL" != postgresql://* ]] || PG_URL="postgresql+psycopg2://${PG_URL#postgresql://}"
MLFLOW_DB="${PCPG_MLFLOW_DB:-pcpg_mlflow}"
OPTUNA_DB="${PCPG_OPTUNA_DB:-pcpg_optuna}"
MLFLOW_PORT="${PCPG_MLFLOW_PORT:-5000}"
MLFLOW_WORKERS="${PCPG_MLFLOW_WORKERS:-2}"
MLFLOW_AUTH="${PCPG_MLFLOW_AUTH:-none}"
RAY_PORT="${PCPG_RAY_PORT:-6379}"
RAY_AUTH="${PCPG_RAY_AUTH_MODE:-token}"
RAY_TEMP="${PCPG_RAY_TEMP:-/tmp/pcpg-ray-$(id -u)}"
STATE="${PCPG_SERVICES_DIR:-${XDG_STATE_HOME:-$HOME/.local/state}/pcpg-services}"
ARTIFACTS="${PCPG_MLFLOW_ARTIFACTS:-$STATE/mlartifacts}"
TIMEOUT="${PCPG_START_TIMEOUT:-300}"
if [[ "${PCPG_BIN:-}" == PATH ]]; then BIN=""
elif [[ -n "${PCPG_BIN:-}" ]]; then BIN="$PCPG_BIN/"
elif [[ -x "$REPO/.venv/bin/python" ]]; then BIN="$REPO/.venv/bin/"
else BIN=""; fi
PY="${BIN}python"
MLFLOW="${BIN}mlflow"
RAY="${BIN}ray"

die() { echo "services.sh: $*" >&2; exit 1; }
refuse() { echo "services.sh: $*" >&2; exit 2; }  # one line, before anything is started
say() { echo "services.sh: $*"; }
is_loopback() { [[ "$1" == 127.* || "$1" == localhost || "$1" == ::1 ]]; }
pidfile() { echo "$STATE/$1.pid"; }
logfile() { echo "$STATE/$1.log"; }
client_host() { if [[ "$HOST" == 0.0.0.0 ]]; then hostname -I 2>/dev/null | awk '{print $1}'; else echo "$HOST"; fi; }
mlflow_url() { echo "http://$(client_host):$MLFLOW_PORT"; }
# the server, then the database, then PCPG_PG_URL's ?options (sslmode=...), if it has any
db_url() {
  local base="${PG_URL%%\?*}" query=""
  [[ "$PG_URL" != *\?* ]] || query="?${PG_URL#*\?}"
  echo "${base%/}/$1$query"
}

# PCPG_PG_URL names the server; the script appends each database name itself.
check_pg_url() {
  local rest="${PG_URL#*://}"; rest="${rest##*@}"; rest="${rest%%\?*}"; rest="${rest%/}"
  [[ "$rest" != */* ]] || refuse "PCPG_PG_URL must name the PostgreSQL server only, without a database \
(it ends in '/${rest#*/}'): e.g. postgresql+psycopg2://postgres@127.0.0.1:5432; the databases are set by \
PCPG_MLFLOW_DB and PCPG_OPTUNA_DB"
}

# Python for the small checks below: the services' own, else any python3 (a bare worker machine).
probe_py() { if command -v "$PY" >/dev/null 2>&1; then "$PY" "$@"; else python3 "$@"; fi; }

# port_busy BIND_HOST CONNECT_HOST PORT: exit 0 if something accepts connections at
# CONNECT_HOST:PORT or holds PORT so that a server could not bind BIND_HOST:PORT ("" = all).
port_busy() { probe_py - "$@" <<'EOF'
import errno, socket, sys
bind_host, connect_host, port = sys.argv[1], sys.argv[2], int(sys.argv[3])
try:
    socket.create_connection((connect_host, port), timeout=2).close()
    sys.exit(0)
except OSError:
    pass
try:
    family = socket.getaddrinfo(bind_host or None, port, type=socket.SOCK_STREAM,
                                flags=socket.AI_PASSIVE)[0][0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as servers do: TIME_WAIT is free
        s.bind((bind_host, port))
except OSError as e:
    sys.exit(0 if e.errno == errno.EADDRINUSE else 1)
sys.exit(1)
EOF
}

# tcp_answers HOST PORT SECONDS: exit 0 if HOST:PORT accepts a TCP connection within SECONDS.
tcp_answers() { probe_py -c '
import socket, sys
try:
    socket.create_connection((sys.argv[1], int(sys.argv[2])), timeout=float(sys.argv[3])).close()
except (OSError, ValueError):
    sys.exit(1)' "$@"
}

# listens_in_group PORT PGID: exit 0 if a process of group PGID listens on TCP PORT (read from
# /proc; where there is no /proc it cannot tell and says yes). Tells our server from another one.
listens_in_group() { probe_py - "$@" <<'EOF'
import os, sys
port, pgid = int(sys.argv[1]), sys.argv[2]
if not os.path.exists("/proc/net/tcp"):
    sys.exit(0)
sockets = set()
for table in ("/proc/net/tcp", "/proc/net/tcp6"):
    try:
        with open(table) as f:
            rows = [line.split() for line in f][1:]
    except OSError:
        continue
    sockets |= {f"socket:[{r[9]}]" for r in rows if r[3] == "0A" and int(r[1].rsplit(":", 1)[1], 16) == port}
for pid in filter(str.isdigit, os.listdir("/proc")):
    try:
        with open(f"/proc/{pid}/stat") as f:
            if f.read().rsplit(")", 1)[1].split()[2] != pgid:
                continue
        for fd in os.listdir(f"/proc/{pid}/fd"):
            if os.readlink(f"/proc/{pid}/fd/{fd}") in sockets:
                sys.exit(0)
    except (OSError, IndexError):
        continue
sys.exit(1)
EOF
}

# The pid of a service this script started, if that process still runs.
running_pid() {
  local f; f="$(pidfile "$1")"
  [[ -f "$f" ]] || return 1
  local pid; pid="$(cat "$f")"
  kill -0 "$pid" 2>/dev/null || return 1
  echo "$pid"
}

# Start "$@" in a new session (its own process group, so stop can end it and every child it
# spawned, and nothing else), detached from this terminal, logging to the service's log file.
launch() {
  local name="$1"; shift
  mkdir -p "$STATE"
  setsid "$@" >"$(logfile "$name")" 2>&1 </dev/null &
  echo $! >"$(pidfile "$name")"
}

# Stop a service: SIGTERM to its process group, SIGKILL to what is left after 30 s.
stop_one() {
  local name="$1" pid
  if ! pid="$(running_pid "$name")"; then say "$name is not running"; rm -f "$(pidfile "$name")"; return 0; fi
  local group="-$pid"
  [[ "$(ps -o pgid= -p "$pid" | tr -d ' ')" == "$pid" ]] || group="$pid"
  kill -TERM -- "$group" 2>/dev/null || true
  for _ in $(seq 30); do kill -0 -- "$group" 2>/dev/null || break; sleep 1; done
  kill -KILL -- "$group" 2>/dev/null || true
  rm -f "$(pidfile "$name")"
  say "stopped $name (pid $pid)"
}

# Wait until "$2 ..." succeeds, failing early with the log's tail if the service process died.
wait_for() {
  local name="$1"; shift
  local deadline=$((SECONDS + TIMEOUT))
  until "$@"; do
    if ! running_pid "$name" >/dev/null; then
      local pid; pid="$(cat "$(pidfile "$name")" 2>/dev/null)" || true
      [[ -z "$pid" ]] || kill -KILL -- "-$pid" 2>/dev/null || true  # what it spawned, if any is left
      rm -f "$(pidfile "$name")"
      if grep -qi "address already in use" "$(logfile "$name")" 2>/dev/null; then
        local port="port"; [[ "$name" != mlflow ]] || port="port $MLFLOW_PORT (PCPG_MLFLOW_PORT)"
        refuse "$name exited: its $port was taken by another process meanwhile; log: $(logfile "$name")"
      fi
      tail -n 30 "$(logfile "$name")" >&2 || true
      die "$name exited during start; full log: $(logfile "$name")"
    fi
    ((SECONDS < deadline)) || die "$name did not come up within ${TIMEOUT}s; log: $(logfile "$name")"
    sleep 1
  done
}

mlflow_healthy() { "$PY" - "$(mlflow_url)" <<'EOF'
import sys, urllib.request
try:
    with urllib.request.urlopen(sys.argv[1] + "/health", timeout=3) as r:
        sys.exit(0 if r.status == 200 else 1)
except Exception:
    sys.exit(1)
EOF
}

# /health answers and the server answering is ours (another one may hold the port).
mlflow_ready() { mlflow_healthy && listens_in_group "$MLFLOW_PORT" "$(cat "$(pidfile mlflow)")"; }

ray_started() { grep -q "Ray runtime started" "$(logfile "$1")" 2>/dev/null; }

# ------------------------------------------------------------------------------------ databases
create_databases() {
  "$PY" - "$(db_url postgres)" "$@" <<'EOF'
import sys
import psycopg2
from psycopg2 import sql
from sqlalchemy.engine import make_url

url = make_url(sys.argv[1])
options = {k: v for k, v in url.query.items() if isinstance(v, str)}  # sslmode=..., as libpq takes them
try:
    conn = psycopg2.connect(host=url.host or "127.0.0.1", port=url.port or 5432, user=url.username,
                            password=url.password, dbname="postgres", connect_timeout=10, **options)
except psycopg2.OperationalError as e:
    sys.exit(f"services.sh: cannot reach PostgreSQL at {url.host}:{url.port or 5432}: "
             f"{str(e).strip().splitlines()[0]}")
conn.autocommit = True
with conn.cursor() as cur:
    for name in sys.argv[2:]:
        cur.execute("SELECT 1 FROM pg_database WHERE datname = %s", (name,))
        if cur.fetchone() is None:
            cur.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
            print(f"services.sh: created database {name}")
conn.close()
EOF
}

# ------------------------------------------------------------------------------------ MLflow
start_mlflow() {
  if pid="$(running_pid mlflow)"; then say "mlflow already running (pid $pid) at $(mlflow_url)"; return 0; fi
  mkdir -p "$STATE"
  [[ "$ARTIFACTS" == *://* ]] || mkdir -p "$ARTIFACTS"
  local args=(server --backend-store-uri "$(db_url "$MLFLOW_DB")" --serve-artifacts
              --artifacts-destination "$ARTIFACTS" --host "$HOST" --port "$MLFLOW_PORT"
              --workers "$MLFLOW_WORKERS")
  local envs=(
    # The job runner (GenAI scorers, trace rollups) spawns ~8 more processes; pcpg needs none.
    "MLFLOW_SERVER_ENABLE_JOB_EXECUTION=${MLFLOW_SERVER_ENABLE_JOB_EXECUTION:-false}")
  case "$MLFLOW_AUTH" in
    none) ;;
    basic)
      "$PY" -c "import flask_wtf" 2>/dev/null || die "PCPG_MLFLOW_AUTH=basic needs Flask-WTF in \
the server's environment (mlflow[auth]); see ops/README.md"
      create_databases "${MLFLOW_DB}_auth"
      local ini="$STATE/basic_auth.ini" key="$STATE/flask_secret_key"
      [[ -f "$ini" ]] || cat >"$ini" <<EOF
[mlflow]
default_permission = ${PCPG_MLFLOW_DEFAULT_PERMISSION:-READ}
database_uri = $(db_url "${MLFLOW_DB}_auth")
admin_username = ${PCPG_MLFLOW_ADMIN:-admin}
authorization_function = mlflow.server.auth:authenticate_request_basic_auth
EOF
      chmod 600 "$ini"
      [[ -f "$key" ]] || (umask 077; "$PY" -c "import secrets; print(secrets.token_hex(32))" >"$key")
      envs+=("MLFLOW_AUTH_CONFIG_PATH=$ini" "MLFLOW_FLASK_SERVER_SECRET_KEY=${MLFLOW_FLASK_SERVER_SECRET_KEY:-$(cat "$key")}")
      args+=(--app-name basic-auth) ;;
    *) die "PCPG_MLFLOW_AUTH must be none or basic, not '$MLFLOW_AUTH'" ;;
  esac
  # shellcheck disable=SC2206 - word splitting of the user's extra arguments is intended
  args+=(${PCPG_MLFLOW_ARGS:-})
  launch mlflow env "${envs[@]}" "$MLFLOW" "${args[@]}"
  say "starting mlflow at $(mlflow_url) (backend $(db_url "$MLFLOW_DB" | sed -E 's#//([^:/@]+):[^@]*@#//\1:***@#'), artifacts $ARTIFACTS)"
  wait_for mlflow mlflow_ready
  local pid
  pid="$(running_pid mlflow)" || die "mlflow exited right after it answered; log: $(logfile mlflow)"
  say "mlflow is up (pid $pid)"
}

# Checks before `start mlflow` creates or launches anything.
preflight_mlflow() {
  running_pid mlflow >/dev/null && return 0
  case "$MLFLOW_AUTH" in none|basic) ;; *) refuse "PCPG_MLFLOW_AUTH must be none or basic, not '$MLFLOW_AUTH'" ;; esac
  local probe="$HOST"; [[ "$HOST" != 0.0.0.0 ]] || probe=127.0.0.1
  if port_busy "$HOST" "$probe" "$MLFLOW_PORT"; then
    refuse "port $MLFLOW_PORT on $HOST is already in use by another process: set PCPG_MLFLOW_PORT to a free port"
  fi
}

# ------------------------------------------------------------------------------------ Ray
ensure_ray_auth() {
  case "$RAY_AUTH" in
    token) [[ -n "${RAY_AUTH_TOKEN:-}" || -f "${RAY_AUTH_TOKEN_PATH:-$HOME/.ray/auth_token}" ]] \
             || RAY_AUTH_MODE=token "$RAY" get-auth-token --generate >/dev/null ;;
    disabled) ;;
    *) refuse "PCPG_RAY_AUTH_MODE must be token or disabled, not '$RAY_AUTH'" ;;
  esac
}

ray_node() {  # ray_node NAME [ray start arguments...]
  local name="$1"; shift
  if pid="$(running_pid "$name")"; then say "$name already running (pid $pid)"; return 0; fi
  preflight_ray_node
  ensure_ray_auth
  mkdir -p "$RAY_TEMP"
  local args=(start --block --node-ip-address "$HOST" --temp-dir "$RAY_TEMP" --disable-usage-stats "$@")
  [[ -z "${PCPG_RAY_CPUS:-}" ]] || args+=(--num-cpus "$PCPG_RAY_CPUS")
  # shellcheck disable=SC2206
  args+=(${PCPG_RAY_ARGS:-})
  # `ray start` gives the raylet a fixed 30 s to register with the GCS; a busy machine can miss
  # that, after which Ray has cleaned up and a second try usually succeeds.
  local attempt attempts="${PCPG_RAY_START_ATTEMPTS:-3}"
  for ((attempt = 1; ; attempt++)); do
    launch "$name" env "RAY_AUTH_MODE=$RAY_AUTH" "$RAY" "${args[@]}"
    if (wait_for "$name" ray_started "$name"); then break; fi
    stop_one "$name" >/dev/null
    ((attempt < attempts)) || die "$name did not start in $attempts attempts; log: $(logfile "$name")"
    say "$name start attempt $attempt failed; retrying"
  done
  say "$name is up (pid $(running_pid "$name")); auth mode: $RAY_AUTH"
}

# Checks before a Ray node is launched (any node).
preflight_ray_node() {
  [[ "$HOST" != 0.0.0.0 ]] || refuse "Ray needs an address other nodes can reach: set PCPG_HOST to this machine's IP"
  case "$RAY_AUTH" in token|disabled) ;; *) refuse "PCPG_RAY_AUTH_MODE must be token or disabled, not '$RAY_AUTH'" ;; esac
}

# Checks before `start ray` launches the head: its GCS port (it listens on all interfaces).
preflight_ray() {
  running_pid ray >/dev/null && return 0
  preflight_ray_node
  if port_busy "" "$HOST" "$RAY_PORT"; then
    refuse "port $RAY_PORT is already in use on this machine (another Ray head, redis, ...): set PCPG_RAY_PORT to a free port"
  fi
}

# Checks before `join HOST:PORT`: the address is well formed and a head answers there.
preflight_join() {
  local addr="$1"
  [[ "$addr" =~ ^[^[:space:]]+:[0-9]+$ ]] || refuse "usage: services.sh join HEAD_IP:PORT (got '$addr')"
  running_pid ray-worker >/dev/null && return 0
  preflight_ray_node
  local host="${addr%:*}"; host="${host#[}"; host="${host%]}"  # [::1]:6379 too
  tcp_answers "$host" "${addr##*:}" 5 \
    || refuse "no Ray head answers at $addr (no TCP connection within 5 s): check the address and that the head runs"
}

start_ray() {
  ray_node ray --head --port "$RAY_PORT" --include-dashboard=false
  is_loopback "$HOST" && say "note: Ray advertises this machine's address even for PCPG_HOST=$HOST and \
listens on all interfaces; token auth is what keeps others out"
  say "clients: --ray-address $(client_host):$RAY_PORT"
}

# ------------------------------------------------------------------------------------ commands
status_one() {
  local name="$1" pid
  if pid="$(running_pid "$name")"; then
    if [[ "$name" == mlflow ]] && ! mlflow_healthy; then say "mlflow: pid $pid, not answering at $(mlflow_url)"; return 1; fi
    say "$name: running (pid $pid, log $(logfile "$name"))"
  else
    say "$name: stopped"; return 1
  fi
}

print_env() {
  check_pg_url
  cat <<EOF
export MLFLOW_TRACKING_URI=$(mlflow_url)
export RAY_ADDRESS=$(client_host):$RAY_PORT
export RAY_AUTH_MODE=$RAY_AUTH
export RAY_ENABLE_UV_RUN_RUNTIME_ENV=0   # only while every node runs this same checkout and venv
# pcpg tune --optuna-storage $(db_url "$OPTUNA_DB")
EOF
}

what="${2:-all}"
case "${1:-}" in
  start)
    # Every check first: a refusal (exit 2) leaves no database, process or pid file behind.
    case "$what" in
      all) check_pg_url; preflight_mlflow; preflight_ray
           create_databases "$MLFLOW_DB" "$OPTUNA_DB"; start_mlflow; start_ray ;;
      db) check_pg_url; create_databases "$MLFLOW_DB" "$OPTUNA_DB" ;;
      mlflow) check_pg_url; preflight_mlflow; create_databases "$MLFLOW_DB"; start_mlflow ;;
      ray) preflight_ray; start_ray ;;
      *) refuse "unknown service '$what' (all, db, mlflow, ray)" ;;
    esac ;;
  stop)
    case "$what" in
      all) stop_one ray; stop_one mlflow ;;
      mlflow|ray|ray-worker) stop_one "$what" ;;
      *) refuse "unknown service '$what' (all, mlflow, ray, ray-worker)" ;;
    esac ;;
  status)
    case "$what" in
      all) rc=0; status_one mlflow || rc=1; status_one ray || rc=1; exit $rc ;;
      mlflow|ray|ray-worker) status_one "$what" ;;
      *) refuse "unknown service '$what' (all, mlflow, ray, ray-worker)" ;;
    esac ;;
  env) print_env ;;
  join)
    [[ -n "${2:-}" ]] || refuse "usage: services.sh join HEAD_IP:PORT"
    preflight_join "$2"
    ray_node ray-worker --address "$2" ;;
  *) sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; exit 2 ;;
esac
