#!/usr/bin/env bash
# Make sure a Redis server answers at 127.0.0.1:6379 (the service tests talk to a real one);
# start a throw-away one (no persistence) if it does not.
set -euo pipefail
if redis-cli -h 127.0.0.1 -p 6379 ping >/dev/null 2>&1; then
    exit 0
fi
if ! command -v redis-server >/dev/null; then
    echo "redis-server is not installed (Debian: apt-get install redis-server)" >&2
    exit 1
fi
redis-server --daemonize yes --bind 127.0.0.1 --port 6379 --save "" --appendonly no \
    --logfile "${TMPDIR:-/tmp}/litege-test-redis.log"
for _ in $(seq 100); do
    redis-cli -h 127.0.0.1 -p 6379 ping >/dev/null 2>&1 && exit 0
    sleep 0.1
done
echo "redis-server did not start; see ${TMPDIR:-/tmp}/litege-test-redis.log" >&2
exit 1
