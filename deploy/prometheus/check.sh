#!/usr/bin/env bash
# Checks the Prometheus files with promtool (Debian package `prometheus`): the configuration,
# the rules, and the rules' unit tests. Opt-in, not part of `cargo test`; the metric names
# themselves are checked against a live server by server/tests/metrics.rs.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")"
command -v promtool >/dev/null || {
    echo "check.sh: promtool not found (apt-get install prometheus)" >&2
    exit 2
}
# The scrape config names a token file; check against a stand-in.
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sed "s|/etc/prometheus/repose.token|$tmp/token|" prometheus.yml >"$tmp/prometheus.yml"
cp repose-alerts.yml "$tmp/"
echo stand-in >"$tmp/token"
promtool check config "$tmp/prometheus.yml"
promtool check rules repose-alerts.yml
promtool test rules repose-alerts.test.yml
