#!/usr/bin/env bash
# Resident memory an idle `gatewatch serve` keeps after rounds of day-long history answers.
#
# Makes a store holding a day of one gate (`bench history`, 17 280 real rows), serves it, sends
# ROUNDS rounds of 4 concurrent `GET /api/v1/gates/g00/history?limit=20000` (28.8 MB of JSON
# each, the route's 4 places) and prints VmRSS 2 s after each round. Extra arguments are
# passed to `serve` as environment, e.g. GLIBC_TUNABLES=glibc.malloc.arena_max=2.
# docs/benchmarks.md, "Memory held after history answers (session 61)".
#
#   benches/history_rss.sh target/release/gatewatch [VAR=VALUE ...]
set -euo pipefail
bin=$(realpath "${1:?usage: history_rss.sh GATEWATCH_BINARY [VAR=VALUE ...]}")
shift
rounds=${ROUNDS:-4}
port=${PORT:-19464}
dir=$(mktemp -d)
trap 'kill "$pid" 2>/dev/null || true; rm -rf "$dir"' EXIT
"$bin" bench history --gates 1 --hours 24 --queries 1 --db "$dir/h.db" > /dev/null
printf '[server]\nlisten = "127.0.0.1:%s"\n[storage]\npath = "%s/h.db"\n' "$port" "$dir" \
    > "$dir/serve.toml"
env "$@" "$bin" serve --config "$dir/serve.toml" > "$dir/serve.log" 2>&1 &
pid=$!
for _ in $(seq 50); do
    curl -sf -o /dev/null "http://127.0.0.1:$port/readyz" && break
    sleep 0.2
done
rss() { awk '/VmRSS/ {printf "%.0f", $2 / 1024}' "/proc/$pid/status"; }
echo "start: $(rss) MiB"
for r in $(seq "$rounds"); do
    clients=()
    for _ in 1 2 3 4; do
        curl -sf -o /dev/null "http://127.0.0.1:$port/api/v1/gates/g00/history?limit=20000" &
        clients+=($!)
    done
    wait "${clients[@]}"
    sleep 2
    echo "after round $r: $(rss) MiB"
done
