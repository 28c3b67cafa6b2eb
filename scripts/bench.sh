#!/usr/bin/env bash
# The full bench (docs/benchmarks.md): the release build, every row including the whole
# commands on inputs of gigabytes (`--whole`, about 10 minutes on 2 cores), each held to
# its recorded floor (`--check`). Extra arguments go to `dncal bench` (e.g. --json,
# --python PYTHON). `.ci/run` runs the short form instead.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked --bin dncal
exec target/release/dncal bench --whole --check "$@"
